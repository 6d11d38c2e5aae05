"""A COLMAP sparse model (cameras + images, text or binary) read into Cameras: one camera per COLMAP image.

The layout is COLMAP's own (src/colmap/scene/reconstruction_io_text.cc / _binary.cc):

- cameras.txt: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...` per line; '#' comments.
- images.txt: two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then the image's 2-D
  points (ignored here; the line may be empty). (QW, QX, QY, QZ) and (TX, TY, TZ) are the world-to-camera
  rotation and translation: X_cam = R(q) X_world + t, camera axes x right, y down, z forward (OpenCV's).
- cameras.bin: uint64 count, then per camera uint32 id, int32 model id, uint64 width, uint64 height,
  float64 params; images.bin: uint64 count, then per image uint32 id, 4 + 3 float64 (q, t), uint32 camera id,
  a NUL-terminated name, uint64 point count, that many (float64 x, float64 y, uint64 point3D id). Little-endian.

COLMAP puts the centre of the top-left pixel at (0.5, 0.5), torchrefl at (0, 0): cx and cy are converted by
-0.5. A camera is named by its image's NAME (the path COLMAP was given, e.g. `IMG_0001.JPG`). rigs / frames /
points3D files are not read.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from torchrefl.capture.cameras import Cameras
from torchrefl.errors import CaptureError

#: COLMAP's camera model ids (src/colmap/sensor/models.h), to name an unsupported one
MODEL_NAMES = (
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "OPENCV_FISHEYE",
    "FULL_OPENCV",
    "FOV",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "THIN_PRISM_FISHEYE",
    "RAD_TAN_THIN_PRISM_FISHEYE",
    "SIMPLE_DIVISION",
    "DIVISION",
    "SIMPLE_FISHEYE",
    "FISHEYE",
    "EUCM",
    "EQUIRECTANGULAR",
)
#: supported model -> its parameter names in COLMAP's order
SUPPORTED = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
}
#: COLMAP's pixel-centre offset: its top-left pixel centre is (0.5, 0.5), torchrefl's (0, 0)
PIXEL_CENTRE = 0.5
#: largest |1 - |q|| accepted (COLMAP writes unit quaternions to 17 digits)
QUATERNION_TOLERANCE = 1e-3


@dataclass(frozen=True)
class ColmapCamera:
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclass(frozen=True)
class ColmapImage:
    image_id: int
    q: tuple[float, float, float, float]  # (w, x, y, z), world-to-camera
    t: tuple[float, float, float]
    camera_id: int
    name: str


def _unsupported(model: str, where: str) -> CaptureError:
    return CaptureError(
        f"{where}: camera model {model} is not supported (supported: {', '.join(SUPPORTED)}); undistort the "
        "images (colmap image_undistorter gives PINHOLE cameras) or reconstruct with one of these models"
    )


def _camera(model: str, width, height, params: list[float], where: str) -> ColmapCamera:
    if model not in SUPPORTED:
        raise _unsupported(model, where)
    if len(params) != len(SUPPORTED[model]):
        raise CaptureError(
            f"{where}: camera model {model} has {len(params)} parameters, expected {len(SUPPORTED[model])} "
            f"({', '.join(SUPPORTED[model])})"
        )
    return ColmapCamera(model, int(width), int(height), tuple(float(p) for p in params))


def read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields, where = line.split(), f"{path}, line {number}"
        if len(fields) < 4:
            raise CaptureError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., got {line!r}")
        try:
            camera_id, width, height = int(fields[0]), int(fields[2]), int(fields[3])
            params = [float(x) for x in fields[4:]]
        except ValueError:
            raise CaptureError(f"{where}: non-numeric value in {line!r}") from None
        cameras[camera_id] = _camera(fields[1], width, height, params, f"{where}: camera {camera_id}")
    return cameras


def read_images_text(path: Path) -> list[ColmapImage]:
    """Images in file order; the line after each image line is its 2-D points, whatever it holds."""
    images = []
    lines = path.read_text().splitlines()
    number = 0
    while number < len(lines):
        line = lines[number].strip()
        number += 1
        if not line or line.startswith("#"):
            continue
        fields = line.split(maxsplit=9)
        if len(fields) != 10:
            raise CaptureError(
                f"{path}, line {number}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got {line!r}"
            )
        try:
            values = [float(x) for x in fields[1:8]]
            image_id, camera_id = int(fields[0]), int(fields[8])
        except ValueError:
            raise CaptureError(f"{path}, line {number}: non-numeric value in {line!r}") from None
        images.append(ColmapImage(image_id, tuple(values[:4]), tuple(values[4:]), camera_id, fields[9].strip()))
        number += 1  # the points line
    return images


class _Bytes:
    """Little-endian reads from a file's bytes; CaptureError naming the file when it ends early."""

    def __init__(self, path: Path):
        self.path, self.data, self.pos = path, path.read_bytes(), 0

    def read(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise CaptureError(f"{self.path}: file ends at byte {len(self.data)}, expected more (truncated?)")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def skip(self, size: int) -> None:
        if self.pos + size > len(self.data):
            raise CaptureError(f"{self.path}: file ends at byte {len(self.data)}, expected more (truncated?)")
        self.pos += size

    def name(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise CaptureError(f"{self.path}: an image name is not NUL-terminated (truncated?)")
        raw, self.pos = self.data[self.pos : end], end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise CaptureError(f"{self.path}: image name {raw!r} is not UTF-8") from None


def read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
    stream = _Bytes(path)
    cameras = {}
    for _ in range(stream.read("Q")[0]):
        camera_id, model_id, width, height = stream.read("IiQQ")
        where = f"{path}: camera {camera_id}"
        model = MODEL_NAMES[model_id] if 0 <= model_id < len(MODEL_NAMES) else f"with id {model_id}"
        if model not in SUPPORTED:
            raise _unsupported(model, where)
        params = list(stream.read("d" * len(SUPPORTED[model])))
        cameras[camera_id] = _camera(model, width, height, params, where)
    return cameras


def read_images_binary(path: Path) -> list[ColmapImage]:
    stream = _Bytes(path)
    images = []
    for _ in range(stream.read("Q")[0]):
        image_id, qw, qx, qy, qz, tx, ty, tz, camera_id = stream.read("IdddddddI")
        name = stream.name()
        stream.skip(stream.read("Q")[0] * struct.calcsize("<ddQ"))
        images.append(ColmapImage(image_id, (qw, qx, qy, qz), (tx, ty, tz), camera_id, name))
    return images


def model_files(folder: Path) -> tuple[Path, Path]:
    """(cameras, images) files of the model in `folder`: the binary pair when both are there, else the text
    pair; CaptureError naming what is missing."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: COLMAP model folder not found (expected cameras.bin/.txt and images.bin/.txt)")
    for ext in ("bin", "txt"):
        cameras, images = folder / f"cameras.{ext}", folder / f"images.{ext}"
        if cameras.is_file() and images.is_file():
            return cameras, images
    found = sorted(p.name for p in folder.iterdir() if p.stem in ("cameras", "images"))
    raise CaptureError(
        f"{folder}: no complete COLMAP model (expected cameras.bin + images.bin or cameras.txt + images.txt; "
        f"found {', '.join(found) or 'neither'})"
    )


def _rotation(image: ColmapImage, where: str) -> np.ndarray:
    q = np.array(image.q, dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if not np.isfinite(norm) or abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise CaptureError(
            f"{where}: image {image.image_id} ('{image.name}') has quaternion {image.q} of length {norm:.6g}, "
            "expected a unit quaternion (QW QX QY QZ)"
        )
    return Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()


def _intrinsics(camera: ColmapCamera) -> tuple[float, float, float, float, list[float]]:
    """(fx, fy, cx, cy, [k1, k2, p1, p2, k3]) in torchrefl's pixel convention."""
    p = dict(zip(SUPPORTED[camera.model], camera.params))
    fx, fy = p.get("fx", p.get("f")), p.get("fy", p.get("f"))
    k1 = p.get("k1", p.get("k", 0.0))
    distortion = [k1, p.get("k2", 0.0), p.get("p1", 0.0), p.get("p2", 0.0), 0.0]
    return fx, fy, p["cx"] - PIXEL_CENTRE, p["cy"] - PIXEL_CENTRE, distortion


def read_colmap_model(folder) -> Cameras:
    """One camera per image of the COLMAP model in `folder` (binary preferred when both forms are there), in
    image-id order, named by the images' names. CaptureError for an unsupported camera model, an image whose
    camera the model lacks, malformed or truncated files (and Cameras.validate's checks)."""
    cameras_path, images_path = model_files(folder)
    binary = cameras_path.suffix == ".bin"
    cameras = (read_cameras_binary if binary else read_cameras_text)(cameras_path)
    images = sorted((read_images_binary if binary else read_images_text)(images_path), key=lambda im: im.image_id)
    if not images:
        raise CaptureError(f"{images_path}: the model has no image")
    rows = []
    for image in images:
        if image.camera_id not in cameras:
            raise CaptureError(
                f"{images_path}: image {image.image_id} ('{image.name}') uses camera {image.camera_id}, which "
                f"{cameras_path} does not have"
            )
        camera = cameras[image.camera_id]
        rows.append((camera.width, camera.height, *_intrinsics(camera), _rotation(image, str(images_path)), image.t))
    columns = list(zip(*rows))
    return Cameras.from_arrays(
        [image.name for image in images],
        *columns[:6],
        np.array(columns[6]),
        np.array(columns[7]),
        np.array(columns[8]),
        source=str(Path(folder)),
    )
