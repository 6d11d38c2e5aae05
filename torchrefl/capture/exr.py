"""OpenEXR images in: linear float samples (HALF or FLOAT channels), read with the `openexr` package (3.x).

A sample is read as it is, a linear fraction of the sensor's full range (1.0 = full range; nothing is divided,
clipped or gamma-decoded). The channels must be R, G, B or Y (grey), optionally with A (dropped); the file's
data window must be its display window; NaN or infinite samples are an error naming the file. core/exr.py's
`openexr_module` is the one import of the package (a MissingPackageError naming the file and the install command
without it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.core.exr import openexr_module
from torchrefl.errors import CaptureError

EXR_MAGIC = b"\x76\x2f\x31\x01"
#: the bit depth images.read_image reports for EXR files (their samples are decoded to float32)
EXR_BITS = 32
_LAYOUTS = (("R", "G", "B"), ("Y",))


def is_exr(path: Path) -> bool:
    """The file starts with OpenEXR's magic number."""
    with open(path, "rb") as fh:
        return fh.read(4) == EXR_MAGIC


def _open(path: Path, header_only: bool):
    OpenEXR = openexr_module(path)
    try:
        return OpenEXR.File(str(path), separate_channels=True, header_only=header_only)
    except Exception as exc:  # the binding raises RuntimeError / bare exceptions for damaged files
        raise CaptureError(f"{path}: not a readable OpenEXR image ({exc})") from None


def _window(path: Path, header: dict) -> tuple[int, int]:
    """(width, height) of the data window; CaptureError when it is not the display window."""
    lo, hi = (np.asarray(a) for a in header["dataWindow"])
    dlo, dhi = (np.asarray(a) for a in header.get("displayWindow", header["dataWindow"]))
    if not (np.array_equal(lo, dlo) and np.array_equal(hi, dhi)):
        raise CaptureError(
            f"{path}: data window {lo.tolist()}-{hi.tolist()} differs from the display window "
            f"{dlo.tolist()}-{dhi.tolist()} (expected a whole image, pixel (0, 0) at the top left)"
        )
    return int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)


def exr_size(path) -> tuple[int, int]:
    """(width, height) of an OpenEXR image from its header."""
    path = Path(path)
    with _open(path, header_only=True) as f:
        return _window(path, f.header())


def read_exr(path) -> np.ndarray:
    """(H, W, C) float32 samples of an OpenEXR image, C = 3 (R, G, B) or 1 (Y); CaptureError naming the file for
    other channel sets, integer (UINT) channels, several parts, a cropped data window or NaN / infinite samples."""
    path = Path(path)
    with _open(path, header_only=False) as f:
        if len(f.parts) != 1:
            raise CaptureError(f"{path}: an OpenEXR file of {len(f.parts)} parts, expected one (a single image)")
        width, height = _window(path, f.header())
        channels = f.channels()
        names = set(channels) - {"A"}
        layout = next((c for c in _LAYOUTS if names == set(c)), None)
        if layout is None:
            raise CaptureError(
                f"{path}: OpenEXR channels {', '.join(sorted(channels))}, expected R, G, B or Y (optionally with A)"
            )
        pixels = [np.asarray(channels[c].pixels) for c in layout]
    for c, p in zip(layout, pixels):
        if p.dtype.kind != "f":
            raise CaptureError(f"{path}: OpenEXR channel {c} holds {p.dtype} samples, expected HALF or FLOAT")
        if p.shape != (height, width):
            raise CaptureError(f"{path}: OpenEXR channel {c} is {p.shape}, expected ({height}, {width}) (subsampled?)")
    image = np.stack(pixels, axis=-1).astype(np.float32)
    bad = ~np.isfinite(image)
    if bad.any():
        raise CaptureError(f"{path}: {int(bad.sum())} NaN or infinite samples (expected finite linear values)")
    return image
