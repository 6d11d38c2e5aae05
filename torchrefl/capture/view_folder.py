"""The metadata of a mesh_views folder: images.json joined with its cameras (cameras.json or a COLMAP model) and
lights.json, every pairing and image size checked before any pixel is read.

The mesh and the texel atlas are read elsewhere; the loader joins the two.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch

from torchrefl.capture.cameras import Cameras
from torchrefl.capture.cameras_json import read_cameras_json
from torchrefl.capture.colmap import read_colmap_model
from torchrefl.capture.images import image_info, read_image
from torchrefl.capture.images_json import IMAGES_JSON, ViewList, read_images_json
from torchrefl.capture.lights_json import LIGHTS_JSON, Lights, read_lights_json
from torchrefl.errors import CaptureError


@dataclass(frozen=True)
class ViewFolder:
    """A mesh_views folder's metadata.

    cameras, lights, views: cameras.json / the COLMAP model, lights.json, images.json.
    camera_index, light_index: (I,) int64, image i's camera in `cameras` and light in `lights`.
    paths, masks: image i's file and mask file (None: no mask).
    bits: the images' common bit depth (8 or 16; 32 for OpenEXR images, float samples).
    warnings: cameras or lights that no image uses.
    """

    folder: Path
    cameras: Cameras
    lights: Lights
    views: ViewList
    camera_index: np.ndarray
    light_index: np.ndarray
    paths: tuple[Path, ...]
    masks: tuple[Optional[Path], ...]
    bits: int
    warnings: tuple[str, ...]

    def read_image(self, i: int) -> np.ndarray:
        """Image i as (H, W, 3) float32 linear fractions of full range (sRGB decoded when the folder's
        encoding is srgb); the exposure factor is not applied (saturation is judged on these values)."""
        image, _ = read_image(self.paths[i])
        if self.views.encoding == "srgb":
            from kornia.color import rgb_to_linear_rgb

            image = rgb_to_linear_rgb(torch.from_numpy(image).permute(2, 0, 1)).permute(1, 2, 0).numpy()
        return image

    def read_mask(self, i: int) -> Optional[np.ndarray]:
        """(H, W) bool of image i's mask (True where any channel is non-zero), or None."""
        if self.masks[i] is None:
            return None
        return read_image(self.masks[i])[0].max(axis=-1) > 0


def _cameras(folder: Path, views: ViewList) -> Cameras:
    path = folder / views.cameras
    if path.is_dir():
        return read_colmap_model(path)
    if path.suffix.lower() == ".json":
        return read_cameras_json(path)
    raise CaptureError(
        f"{views.source}: .cameras is {views.cameras!r}: {path} is neither a .json file nor a folder holding a "
        "COLMAP model (cameras.bin/.txt, images.bin/.txt)"
    )


def _missing(kind: str, name: str, known: tuple[str, ...], source: str, colmap: bool) -> str:
    listed = ", ".join(repr(n) for n in known[:5]) + (", ..." if len(known) > 5 else "")
    holder = f"the COLMAP model {source} has no image named so" if colmap else f"{source} does not define it"
    return f"names {kind} {name!r}, but {holder} (it has {len(known)}: {listed})"


def _index(views: ViewList, cameras: Cameras, lights: Lights) -> tuple[np.ndarray, np.ndarray]:
    colmap = not cameras.source.lower().endswith(".json")
    cam_of = {n: i for i, n in enumerate(cameras.names)}
    light_of = {n: i for i, n in enumerate(lights.names)}
    cams, lits = [], []
    for i, view in enumerate(views.images):
        if view.camera not in cam_of:
            why = _missing("camera", view.camera, cameras.names, cameras.source, colmap)
            raise CaptureError(f"{views.source}: .images[{i}] {why}")
        if view.light not in light_of:
            raise CaptureError(
                f"{views.source}: .images[{i}] {_missing('light', view.light, lights.names, lights.source, False)}"
            )
        cams.append(cam_of[view.camera])
        lits.append(light_of[view.light])
    return np.array(cams, dtype=np.int64), np.array(lits, dtype=np.int64)


def _check_files(folder: Path, views: ViewList, cameras: Cameras, camera_index: np.ndarray) -> int:
    """CaptureError for a missing or repeated image file, a size that differs from the camera's, mixed bit
    depths or 16-bit images called srgb; returns the common bit depth."""
    seen: dict[Path, int] = {}
    bits = None
    for i, view in enumerate(views.images):
        key = f"{views.source}: .images[{i}]"
        path = folder / view.file
        if not path.is_file():
            raise CaptureError(f"{key}.file: image file {path} is missing")
        real = path.resolve()
        if real in seen:
            raise CaptureError(f"{key}.file: {path} is also .images[{seen[real]}]'s file (one photograph per entry)")
        seen[real] = i
        c = int(camera_index[i])
        expected = (int(cameras.width[c]), int(cameras.height[c]))
        files = [(path, "file")] + ([(folder / view.mask, "mask")] if view.mask else [])
        for file, field in files:
            if not file.is_file():
                raise CaptureError(f"{key}.{field}: {field} file {file} is missing")
            width, height, depth = image_info(file)
            if (width, height) != expected:
                raise CaptureError(
                    f"{key}.{field}: {file} is {width}x{height} pixels, but its camera {view.camera!r} is "
                    f"{expected[0]}x{expected[1]} ({cameras.source})"
                )
            if field == "file" and bits is not None and depth != bits:
                raise CaptureError(f"{key}.file: {path} is a {depth}-bit image, expected {bits}-bit like .images[0]")
            bits = depth if field == "file" else bits
    if views.encoding == "srgb" and bits != 8:
        raise CaptureError(f"{views.source}: .encoding is srgb, but the images are {bits}-bit (sRGB images are 8-bit)")
    return int(bits)


def _unused(views: ViewList, cameras: Cameras, lights: Lights, camera_index, light_index) -> list[str]:
    out = []
    for what, names, used in (("camera", cameras.names, camera_index), ("light", lights.names, light_index)):
        unused = sorted(set(range(len(names))) - set(used.tolist()))
        if unused:
            listed = ", ".join(repr(names[i]) for i in unused[:3])
            out.append(f"{len(unused)} {what}(s) that no image of {views.source} uses, e.g. {listed}")
    return out


def read_view_folder(folder) -> ViewFolder:
    """Read and cross-check a mesh_views folder's images.json, cameras and lights.json."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: capture folder not found")
    views = read_images_json(folder / IMAGES_JSON)
    cameras = _cameras(folder, views)
    lights = read_lights_json(folder / LIGHTS_JSON)
    camera_index, light_index = _index(views, cameras, lights)
    bits = _check_files(folder, views, cameras, camera_index)
    return ViewFolder(
        folder=folder,
        cameras=cameras,
        lights=lights,
        views=views,
        camera_index=camera_index,
        light_index=light_index,
        paths=tuple(folder / v.file for v in views.images),
        masks=tuple(folder / v.mask if v.mask else None for v in views.images),
        bits=bits,
        warnings=tuple(_unused(views, cameras, lights, camera_index, light_index)),
    )
