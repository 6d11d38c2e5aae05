"""OpenEXR files through the `openexr` package (PyPI openexr 3.x, its own C++ library in the wheel; needs numpy).

The one place torchrefl imports OpenEXR (`openexr_module`; capture/exr.py reads images through it): write_exr
writes float32 channels (scan-line, ZIP compression).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.errors import MissingPackageError, OutputError


def openexr_module(path, why: str = "reading"):
    """The OpenEXR module; MissingPackageError naming `path` when the `openexr` package is not installed."""
    try:
        import OpenEXR
    except ImportError:
        raise MissingPackageError(
            f"{path}: {why} an OpenEXR image needs the 'openexr' package (3.x), which is not installed: "
            "pip install openexr"
        ) from None
    return OpenEXR


def write_exr(path, channels: dict[str, np.ndarray]) -> None:
    """Write `channels` (name -> (H, W) array, all the same shape; e.g. R, G, B, A or Y) as a float32 OpenEXR file.
    OutputError naming the file when the channels are empty, differ in shape or the file cannot be written."""
    path = Path(path)
    OpenEXR = openexr_module(path, "writing")
    shapes = {np.shape(a) for a in channels.values()}
    if not channels or len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise OutputError(f"{path}: expected channels of one (H, W) shape, got {sorted(shapes)}")
    data = {name: np.ascontiguousarray(a, dtype=np.float32) for name, a in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    try:
        with OpenEXR.File(header, data) as f:
            f.write(str(path))
    except Exception as exc:  # the library raises plain exceptions on I/O errors
        raise OutputError(f"{path}: cannot write the OpenEXR file ({exc})") from None
