"""Loader for photometric stereo captures in the DiLiGenT layout.

A folder holds, for one object seen by a fixed orthographic camera:

- NNN.png: one linear 8- or 16-bit RGB image per directional light (filenames.txt, when present,
  lists them in light order; otherwise the NNN.png files sorted by name).
- light_directions.txt: P x 3 unit vectors towards each light, camera frame (x right, y up,
  z towards the camera; image row 0 is the top).
- light_intensities.txt: P x 3 RGB intensity of each light (> 0).
- mask.png: object mask, a pixel belongs to the object when any channel is non-zero.
- Normal_gt.mat: MATLAB file with key `Normal_gt`, (H, W, 3) unit normals in the camera frame.

The texel grid is the image: one texel per mask pixel. There is no depth, so positions are pixel
coordinates on the z = 0 plane, there is no mesh, and cast shadows are unknown (`shadowed` is all
False: only attached shadows, n.l <= 0, are excluded). Only local transport applies.
"""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.base import Capture, CaptureLoader, Log
from torchrefl.capture.checks import (
    distinct_image_files,
    image_content_checks,
    implied_albedo_check,
    light_indices,
    observations_left,
)
from torchrefl.capture.images import read_image, read_images
from torchrefl.config import Config
from torchrefl.core.observations import Observations
from torchrefl.core.surface import UNIT_TOLERANCE, Surface
from torchrefl.errors import CaptureError, DataMissingError, GeometryError

FILENAMES = "filenames.txt"
LIGHT_DIRECTIONS = "light_directions.txt"
LIGHT_INTENSITIES = "light_intensities.txt"
MASK = "mask.png"
NORMALS = "Normal_gt.mat"
NORMALS_KEY = "Normal_gt"
# light directions are stored with 4 decimals: accept rounding, reject vectors that are not unit
DIRECTION_TOLERANCE = 1e-2
_IMAGE_NAME = re.compile(r"^\d+\.png$", re.IGNORECASE)
#: the DiLiGenT benchmark's project page (torchrefl does not ship the data)
DILIGENT_URL = "https://sites.google.com/site/photometricstereodata/single"


def _require_file(path: Path) -> Path:
    if not path.is_file():
        raise CaptureError(f"{path}: file missing (a photometric stereo folder needs it, DiLiGenT layout)")
    return path


def read_table(path: Path, columns: int = 3) -> np.ndarray:
    """(R, columns) float64 rows of a whitespace- or comma-separated text table; blank lines and
    '#' comments are skipped. CaptureError naming the file and line for non-numeric values or a
    wrong number of columns."""
    rows = []
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise CaptureError(f"{path}: cannot read text table ({exc})") from None
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != columns:
            raise CaptureError(
                f"{path}, line {number}: {len(fields)} values {line!r}, expected {columns} numbers per line"
            )
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            raise CaptureError(
                f"{path}, line {number}: non-numeric value in {line!r}, expected {columns} numbers"
            ) from None
    return np.array(rows, dtype=np.float64).reshape(-1, columns)


def _line_numbers(path: Path) -> list[int]:
    """1-based file line of each data row of a table read by read_table."""
    out = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.split("#", 1)[0].strip():
            out.append(number)
    return out


def image_names(folder: Path) -> list[str]:
    """Image file names in light order: filenames.txt when present, else the NNN.png files sorted."""
    listing = folder / FILENAMES
    if listing.is_file():
        names = [ln.strip() for ln in listing.read_text().splitlines() if ln.strip()]
        if not names:
            raise CaptureError(f"{listing}: lists no image (expected one image file name per line)")
        return names
    names = sorted(p.name for p in folder.iterdir() if p.is_file() and _IMAGE_NAME.match(p.name))
    if not names:
        raise CaptureError(f"{folder}: no {FILENAMES} and no NNN.png images (expected the DiLiGenT layout)")
    return names


def _check_rows(path: Path, table: np.ndarray, num_images: int) -> None:
    if table.shape[0] != num_images:
        raise CaptureError(
            f"{path}: {table.shape[0]} rows, expected {num_images} (one row per image; the folder lists {num_images} "
            "images)"
        )


def read_light_directions(path: Path, num_images: int) -> np.ndarray:
    """(P, 3) float64 unit light directions (rounding to 4 decimals is renormalised away)."""
    d = read_table(path)
    _check_rows(path, d, num_images)
    norm = np.linalg.norm(d, axis=1)
    bad = ~np.isfinite(norm) | (np.abs(norm - 1.0) > DIRECTION_TOLERANCE)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise CaptureError(
            f"{path}, line {_line_numbers(path)[row]}: direction {d[row].tolist()} has length {norm[row]:.4g}, "
            f"expected a finite unit vector (+- {DIRECTION_TOLERANCE}); {int(bad.sum())} bad rows"
        )
    return d / norm[:, None]


def read_light_intensities(path: Path, num_images: int) -> np.ndarray:
    """(P, 3) float64 RGB light intensities, finite and > 0."""
    y = read_table(path)
    _check_rows(path, y, num_images)
    bad = ~(np.isfinite(y) & (y > 0)).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise CaptureError(
            f"{path}, line {_line_numbers(path)[row]}: intensity {y[row].tolist()}, expected 3 finite values > 0; "
            f"{int(bad.sum())} bad rows"
        )
    return y


def read_normal_map(path: Path) -> np.ndarray:
    """(H, W, 3) float64 normal map from a MATLAB file (key Normal_gt)."""
    import scipy.io

    try:
        data = scipy.io.loadmat(str(path))
    except NotImplementedError:
        raise CaptureError(
            f"{path}: MATLAB v7.3 (HDF5) files are not supported; re-save it with save(..., '-v7')"
        ) from None
    except Exception as exc:  # scipy raises ValueError/TypeError/OSError for corrupt files
        raise CaptureError(f"{path}: not a readable MATLAB file ({exc})") from None
    if NORMALS_KEY not in data:
        keys = sorted(k for k in data if not k.startswith("__"))
        raise CaptureError(f"{path}: key '{NORMALS_KEY}' missing (found {keys})")
    n = np.asarray(data[NORMALS_KEY])
    if n.ndim != 3 or n.shape[2] != 3 or not np.issubdtype(n.dtype, np.number):
        raise CaptureError(f"{path}: '{NORMALS_KEY}' has shape {n.shape} ({n.dtype}), expected (H, W, 3) numbers")
    return n.astype(np.float64)


def _image_checks(folder: Path, names: list[str], keep: list[int], intensity: np.ndarray) -> list[str]:
    """checks.image_content_checks on the loaded images, plus a warning for NNN.png files no light lists."""
    listing = folder / FILENAMES if (folder / FILENAMES).is_file() else folder
    warnings = image_content_checks(intensity, [folder / names[i] for i in keep])
    on_disk = [p for p in folder.iterdir() if p.is_file() and _IMAGE_NAME.match(p.name)]
    extra = sorted(p.name for p in on_disk if p.name not in set(names))
    if extra:
        warnings.append(
            f"{folder} holds {len(extra)} NNN.png image(s) that {listing.name} does not list "
            f"(e.g. {', '.join(extra[:3])}): a truncated light list?"
        )
    return warnings


def _valid_observations(cos_v, cos_l, saturated, finite, folder: Path) -> np.ndarray:
    removed = {
        "normal facing away from the camera (n.v <= 0)": np.broadcast_to((cos_v <= 0)[None], cos_l.shape),
        "not lit (n.l <= 0)": cos_l <= 0,
        "saturated": saturated,
        "not finite": ~finite,
    }
    valid = ~np.logical_or.reduce(list(removed.values()))
    observations_left(valid, removed, str(folder))
    return valid


def load_photometric_stereo(
    folder,
    *,
    saturation_level: float = 0.995,
    kappa=(math.pi, math.pi, math.pi),
    light_subset=None,
    dtype=torch.float32,
    threads: int = 2,
) -> tuple[Surface, Observations, dict]:
    """Load a DiLiGenT-layout folder into Surface + Observations.

    Surface (T = mask pixels, in row-major order): grid_shape (H, W) of the images;
    positions (T, 3) pixel coordinates x = col - W/2, y = H/2 - row, z = 0, units "px" (orthographic
    camera, no depth); normals (T, 3) from Normal_gt.mat; areas (T,) ones; no mesh.

    Observations (P = images loaded, all or `light_subset` (indices into the image list)):
    intensity (P, T, 3) raw image values as fractions of full range (not divided by the light
    intensities: the model multiplies by light_intensity, so metrics stay on the sensor scale);
    light_intensity (P, 3) from light_intensities.txt; light_dir (P, T, 3) the light's direction at
    every texel (an expanded view: read-only, index it or .clone() it before writing);
    falloff (P, T) ones (directional lights); view_dir (T, 3) = (0, 0, 1) (expanded view);
    saturated (P, T) any channel >= saturation_level; shadowed (P, T) all False, because without
    depth cast shadows cannot be computed (only attached shadows are excluded, through n.l);
    valid (P, T) = n.v > 0 and n.l > 0 and not saturated and finite.

    Stats: texels, lights, bit_depth, saturated_observations (all saturated observations at mask
    pixels), valid_observations, per_light {saturated, valid} lists, load_time_s, warnings (a list of
    strings: what may be wrong with the folder, see torchrefl.capture.checks).

    Raises CaptureError (GeometryError for bad normals) naming the file and what was expected when
    the folder or a file is missing or unreadable, sizes disagree, light tables have the wrong
    number of rows or columns or bad values, the mask selects nothing, or the images cannot be right
    (torchrefl.capture.checks: a file used for two lights, constant images, intensities of the wrong scale,
    no usable observation).
    """
    t0 = time.perf_counter()
    folder = Path(folder)
    kappa_arr = _check_options(folder, saturation_level, kappa)
    names, paths = _image_files(folder)
    dirs_path = _require_file(folder / LIGHT_DIRECTIONS)
    ints_path = _require_file(folder / LIGHT_INTENSITIES)
    mask_path = _require_file(folder / MASK)
    normals_path = _require_file(folder / NORMALS)
    directions = read_light_directions(dirs_path, len(names))
    intensities = read_light_intensities(ints_path, len(names))
    keep = light_indices(
        light_subset, len(names), str(folder / FILENAMES) if (folder / FILENAMES).is_file() else str(folder)
    )
    distinct_image_files([paths[i] for i in keep], [names[i] for i in keep], str(folder))

    mask = _read_mask(mask_path, paths[keep[0]])
    normals = _read_normals(normals_path, mask, paths[keep[0]])
    intensity, bits = read_images([paths[i] for i in keep], threads=threads, pixels=mask)
    warnings = _image_checks(folder, names, keep, intensity)
    if dtype == torch.float64:  # recover the exact v / (2**bits - 1) from the float32 fractions
        full = float(2**bits - 1)
        intensity = np.rint(intensity.astype(np.float64) * full) / full
    surface = _image_surface(mask, normals, dtype, folder)

    obs = _observations(
        intensity,
        normals,
        directions[keep],
        intensities[keep],
        [names[i] for i in keep],
        kappa_arr,
        saturation_level,
        dtype,
        folder,
        ints_path,
    )
    return surface, obs, _load_stats(obs, bits, t0, warnings)


def _load_stats(obs: Observations, bits: int, t0: float, warnings: list[str]) -> dict:
    """load_photometric_stereo's stats (its docstring); t0: perf_counter at the start of the load."""
    saturated, valid = obs.saturated.numpy(), obs.valid.numpy()
    P, T = valid.shape
    return {
        "texels": int(T),
        "lights": int(P),
        "bit_depth": int(bits),
        "saturated_observations": int(saturated.sum()),
        "valid_observations": int(valid.sum()),
        "per_light": {"saturated": saturated.sum(axis=1).tolist(), "valid": valid.sum(axis=1).tolist()},
        "load_time_s": time.perf_counter() - t0,
        "warnings": warnings,
    }


def _observations(
    intensity, normals, dirs, light_intensity, light_names, kappa_arr, saturation_level, dtype, folder, ints_path
) -> Observations:
    """Observations of the loaded lights: intensity (P, T, 3) fractions of full range, normals (T, 3), dirs (P, 3)
    and light_intensity (P, 3) of the loaded lights; checks that observations are left and the implied albedo."""
    P, T = len(dirs), normals.shape[0]
    cos_l = dirs @ normals.T  # (P, T)
    cos_v = normals[:, 2]  # view (0, 0, 1)
    saturated = (intensity >= saturation_level).any(axis=-1)
    finite = np.isfinite(intensity).all(axis=-1)
    valid = _valid_observations(cos_v, cos_l, saturated, finite, folder)
    implied_albedo_check(
        intensity.astype(np.float64),
        valid,
        cos_l,
        np.broadcast_to(light_intensity[:, None, :], intensity.shape),
        kappa_arr,
        str(ints_path),
    )

    light_dir = torch.from_numpy(dirs).to(dtype)[:, None, :].expand(P, T, 3)
    return Observations(
        intensity=torch.from_numpy(intensity).to(dtype),
        valid=torch.from_numpy(valid),
        saturated=torch.from_numpy(saturated),
        shadowed=torch.zeros(P, T, dtype=torch.bool),
        light_dir=light_dir,
        falloff=torch.ones(1, 1, dtype=dtype).expand(P, T),
        light_intensity=torch.from_numpy(light_intensity).to(dtype),
        view_dir=torch.tensor([0.0, 0.0, 1.0], dtype=dtype).expand(T, 3),
        kappa=torch.from_numpy(kappa_arr).to(dtype),
        light_positions=None,
        light_names=light_names,
        source=str(folder),
    )


def _check_options(folder: Path, saturation_level, kappa) -> np.ndarray:
    """The folder, saturation_level and kappa checked (CaptureError); returns kappa as (3,) float64."""
    if not folder.is_dir():
        raise DataMissingError(
            f"{folder}: photometric stereo folder not found (capture.path; expected a folder in the DiLiGenT layout). "
            f"The DiLiGenT data is not shipped with torchrefl: download DiLiGenT from {DILIGENT_URL}, unpack it "
            "and point capture.path at one object's folder, e.g. capture.path=/path/to/DiLiGenT/pmsData/ballPNG"
        )
    if not 0.0 < float(saturation_level) <= 1.0:
        raise CaptureError(f"saturation_level={saturation_level!r} for {folder}, expected a value in (0, 1]")
    kappa_arr = np.asarray(kappa, dtype=np.float64).reshape(-1)
    if kappa_arr.shape != (3,) or not (np.isfinite(kappa_arr) & (kappa_arr > 0)).all():
        raise CaptureError(f"kappa={kappa!r} for {folder}, expected 3 finite values > 0")
    return kappa_arr


def _image_files(folder: Path) -> tuple[list[str], list[Path]]:
    """(image names in light order, their paths), each path checked to exist."""
    names = image_names(folder)
    paths = [folder / name for name in names]
    for p in paths:
        if not p.is_file():
            raise CaptureError(
                f"{p}: image file missing (listed in {folder / FILENAMES})"
                if (folder / FILENAMES).is_file()
                else f"{p}: image file missing"
            )
    return names, paths


def _read_mask(mask_path: Path, first_image: Path) -> np.ndarray:
    """(H, W) bool object mask, checked to match the size of first_image and to select a pixel."""
    mask_img, _ = read_image(mask_path)
    first, _ = read_image(first_image)
    H, W = first.shape[:2]
    if mask_img.shape[:2] != (H, W):
        raise CaptureError(
            f"{mask_path} is {mask_img.shape[1]}x{mask_img.shape[0]}, expected {W}x{H} like {first_image}"
        )
    mask = (mask_img > 0).any(axis=-1)
    del first, mask_img
    if not mask.any():
        raise CaptureError(f"{mask_path}: the mask selects no pixel (expected non-zero pixels on the object)")
    return mask


def _read_normals(normals_path: Path, mask: np.ndarray, first_image: Path) -> np.ndarray:
    """(T, 3) float64 unit normals of the mask pixels (row-major), checked for size and unit length."""
    H, W = mask.shape
    normal_map = read_normal_map(normals_path)
    if normal_map.shape[:2] != (H, W):
        raise CaptureError(
            f"{normals_path}: '{NORMALS_KEY}' is {normal_map.shape[1]}x{normal_map.shape[0]}, expected {W}x{H} "
            f"like {first_image}"
        )
    normals = normal_map[mask]
    length = np.linalg.norm(normals, axis=1)
    bad = ~np.isfinite(length) | (np.abs(length - 1.0) > UNIT_TOLERANCE)
    if bad.any():
        raise GeometryError(
            f"{normals_path}: {int(bad.sum())} of {normals.shape[0]} normals inside {MASK} are NaN or not unit "
            f"length (expected |n| = 1 +- {UNIT_TOLERANCE} on the object)"
        )
    return normals / length[:, None]


def _image_surface(mask: np.ndarray, normals: np.ndarray, dtype, folder: Path) -> Surface:
    """The Surface of the mask pixels: pixel-coordinate positions on z = 0, the given normals, unit areas."""
    H, W = mask.shape
    rows, cols = np.nonzero(mask)
    texel_index = np.flatnonzero(mask.ravel())
    positions = np.column_stack([cols - W / 2.0, H / 2.0 - rows, np.zeros(rows.size)])
    return Surface(
        grid_shape=(H, W),
        texel_index=torch.from_numpy(texel_index.astype(np.int64)),
        positions=torch.from_numpy(positions).to(dtype),
        normals=torch.from_numpy(normals).to(dtype),
        areas=torch.ones(rows.size, dtype=dtype),
        units="px",
        source=str(folder),
    )


class PhotometricStereoLoader(CaptureLoader):
    """capture.kind photometric_stereo: a DiLiGenT-layout folder (directional lights, orthographic camera)."""

    kind = "photometric_stereo"

    def load(self, folder: Path, cfg: Config, log: Log) -> Capture:
        c = cfg.capture
        surface, obs, stats = load_photometric_stereo(
            folder,
            saturation_level=c.saturation_level,
            kappa=tuple(c.kappa),
            light_subset=c.light_subset,
            dtype=cfg.torch_dtype,
            threads=cfg.threads,
        )
        warnings = stats.pop("warnings")
        return Capture(surface, obs, stats, None, Path(folder), warnings)
