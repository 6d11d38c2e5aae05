"""Ground truth of a synthetic capture folder (truth.npz), read and checked.

Keys: pd (H, W, 3), ps (H, W, 3) or (H, W, 1), sigma (H, W) on the capture's texel grid, finite at every
texel of the surface; optional brdf (a name), minnaert_k (a number) and region (H, W) integers (material regions,
-1 none: metrics.json's per-region specular_source). Anything else is a CaptureError
naming the file and the key.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from torchrefl.core.surface import Surface
from torchrefl.errors import CaptureError

TRUTH = "truth.npz"


def _read_npz(path: Path) -> dict:
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except Exception as exc:  # truncated zip, a pickle, not an archive: name the file
        raise CaptureError(f"{path}: unreadable as a numpy .npz archive ({type(exc).__name__}: {exc})") from None


def _grid(data: dict, key: str, shapes: list[tuple], surface: Surface, path: Path) -> np.ndarray:
    if key not in data:
        raise CaptureError(f"{path}: missing key '{key}' (a truth file holds pd, ps and sigma; found {sorted(data)})")
    a = data[key]
    if a.shape not in shapes or not np.issubdtype(a.dtype, np.number):
        raise CaptureError(
            f"{path}: '{key}' is {a.dtype} {a.shape}, expected numbers of shape "
            f"{' or '.join(map(str, shapes))} (the texel grid of range.npy)"
        )
    values = surface.from_grid(a.astype(np.float64)).double()
    bad = ~values.reshape(values.shape[0], -1).isfinite().all(-1)
    if bool(bad.any()):
        raise CaptureError(
            f"{path}: '{key}' is NaN or infinite at {int(bad.sum())} of {len(bad)} texels of the "
            "surface (expected finite values wherever range.npy has one)"
        )
    return values


def load_truth(path: Path, surface: Surface) -> dict:
    """Per-texel truth pd (T, 3), ps (T, C), sigma (T,), region (T,) int64 or None, brdf (str or None), minnaert_k
    from a truth file."""
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: truth file not found")
    data = _read_npz(path)
    H, W = surface.grid_shape
    truth = {
        "pd": _grid(data, "pd", [(H, W, 3)], surface, path),
        "ps": _grid(data, "ps", [(H, W, 3), (H, W, 1)], surface, path),
        "sigma": _grid(data, "sigma", [(H, W)], surface, path),
    }
    brdf = data.get("brdf")
    if brdf is not None and (brdf.shape != () or brdf.dtype.kind != "U"):
        raise CaptureError(f"{path}: 'brdf' is {brdf!r}, expected a BRDF name")
    region = data.get("region")
    if region is not None and (region.shape != (H, W) or not np.issubdtype(region.dtype, np.integer)):
        raise CaptureError(f"{path}: 'region' is {region.dtype} {region.shape}, expected integers of shape {(H, W)}")
    k = data.get("minnaert_k", np.array(1.0))
    if k.size != 1 or not np.issubdtype(k.dtype, np.number) or not math.isfinite(float(k)):
        raise CaptureError(f"{path}: 'minnaert_k' is {k!r}, expected one finite number")
    truth["region"] = None if region is None else surface.from_grid(region.astype(np.int64))
    return {**truth, "brdf": str(brdf) if brdf is not None else None, "minnaert_k": float(k)}
