"""Image I/O at full bit depth: 8- and 16-bit PNG, OpenEXR (and JPEG/TIFF) in, 8- and 16-bit PNG out.

Pillow, imageio and skimage.io silently reduce 16-bit RGB PNGs to 8 bits, which would throw
away most of a linear capture's dynamic range. Images are therefore decoded with kornia_rs
(installed with kornia), which keeps 16-bit samples; Pillow is used only for the 8-bit PNG
variants kornia_rs does not decode (palette, grey + alpha, 1/2/4-bit grey) and for other 8-bit
formats (BMP, ...).

Values are returned as linear fractions of the sensor's full range: v / 255 for 8-bit files,
v / 65535 for 16-bit files, OpenEXR samples as they are (capture.exr; reported as bit depth 32); no gamma is
undone: captures are expected to be linear.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from torchrefl.capture.exr import EXR_BITS, exr_size, is_exr, read_exr
from torchrefl.core.threads import thread_map
from torchrefl.errors import CaptureError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# PNG colour types: 0 grey, 2 RGB, 3 palette, 4 grey + alpha, 6 RGBA.
_KORNIA_PNG_COLOUR_TYPES = (0, 2, 6)
_PIL_8BIT_MODES = ("1", "L", "P", "LA", "PA", "La", "RGB", "RGBA", "RGBa", "RGBX")
_PIL_16BIT_MODES = ("I;16", "I;16B", "I;16L", "I;16N")


def _png_header(path: Path) -> tuple[int, int] | None:
    """(bit depth, colour type) from a PNG's IHDR chunk, or None when the file is not a PNG."""
    with open(path, "rb") as fh:
        head = fh.read(26)
    if len(head) < 26 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        return None
    bit_depth, colour_type = struct.unpack(">BB", head[24:26])
    return bit_depth, colour_type


def _decode_pillow(path: Path, why: str) -> tuple[np.ndarray, int]:
    """8-bit (or 16-bit grey) images Pillow reads without losing depth; (H, W, C) uint8/uint16, bits."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            mode = im.mode
            if mode in _PIL_16BIT_MODES:
                raw = np.asarray(im.convert("I;16") if mode != "I;16" else im).astype(np.uint16)[..., None]
                return raw, 16
            if mode not in _PIL_8BIT_MODES:
                raise CaptureError(f"{path}: unsupported image mode {mode!r} (expected 8- or 16-bit grey, RGB or RGBA)")
            has_alpha = mode in ("LA", "PA", "La", "RGBA", "RGBa") or "transparency" in im.info
            raw = np.asarray(im.convert("RGBA" if has_alpha else "RGB"))
            return raw, 8
    except CaptureError:
        raise
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
        raise CaptureError(f"{path}: not a readable image ({why}; Pillow: {exc})") from None


def _decode(path) -> tuple[np.ndarray, int]:
    """Decode `path` into (H, W, C) uint8 or uint16 samples (C in 1, 3, 4) and the bit depth, or float32 samples
    (C in 1, 3) and EXR_BITS for an OpenEXR file."""
    import kornia_rs

    path = Path(path)
    if not path.is_file():
        what = "a folder" if path.is_dir() else "missing"
        raise CaptureError(f"{path}: image file {what} (expected an 8- or 16-bit PNG or an OpenEXR image)")
    if is_exr(path):
        return read_exr(path), EXR_BITS
    png = _png_header(path)
    if png is not None:
        bit_depth, colour_type = png
        if bit_depth == 16 and colour_type not in _KORNIA_PNG_COLOUR_TYPES:
            raise CaptureError(f"{path}: unsupported 16-bit PNG colour type {colour_type} (expected grey, RGB or RGBA)")
        if bit_depth < 8 or colour_type not in _KORNIA_PNG_COLOUR_TYPES:
            return _decode_pillow(path, f"PNG with bit depth {bit_depth}, colour type {colour_type}")
    try:
        raw = kornia_rs.io.read_image(str(path))
    except Exception as exc:  # kornia_rs raises bare Exception / ValueError for undecodable files
        if png is not None:
            raise CaptureError(f"{path}: not a readable PNG ({exc})") from None
        return _decode_pillow(path, f"kornia_rs: {exc}")
    raw = np.asarray(raw)
    if raw.dtype == np.uint8:
        bits = 8
    elif raw.dtype == np.uint16:
        bits = 16
    else:
        raise CaptureError(f"{path}: unsupported sample type {raw.dtype} (expected 8- or 16-bit integers)")
    if raw.ndim == 2:
        raw = raw[..., None]
    if raw.ndim != 3 or raw.shape[2] not in (1, 3, 4):
        raise CaptureError(f"{path}: unsupported channel layout {raw.shape} (expected 1, 3 or 4 channels)")
    return raw, bits


def _full_scale(bits: int) -> np.float32:
    return np.float32(2**bits - 1)


def _to_float(raw: np.ndarray, bits: int, out: np.ndarray | None = None) -> np.ndarray:
    """(..., C) integer samples (float samples: already fractions) -> (..., 3) float32 fractions of full range (grey
    repeated, alpha dropped)."""
    rgb = raw[..., :3] if raw.shape[-1] >= 3 else raw  # (.., 1) broadcasts over the 3 channels
    if out is None:
        out = np.empty(raw.shape[:-1] + (3,), dtype=np.float32)
    scale = np.float32(1) if raw.dtype.kind == "f" else _full_scale(bits)
    np.divide(rgb, scale, out=out, dtype=np.float32, casting="unsafe")
    return out


def read_image(path) -> tuple[np.ndarray, int]:
    """Read one image.

    Returns image: (H, W, 3) float32, linear values as fractions of full range
    (v / 255 for 8-bit files, v / 65535 for 16-bit files, OpenEXR samples as they are), and the bit depth (8 or
    16; EXR_BITS for OpenEXR).
    Grey images become 3 equal channels; an alpha channel is dropped.
    Raises CaptureError naming the file when it is missing, unreadable or of an unsupported
    depth or channel count.
    """
    raw, bits = _decode(path)
    return _to_float(raw, bits), bits


def _size(shape) -> str:
    return f"{shape[1]}x{shape[0]}"


def _colour(raw: np.ndarray) -> str:
    """'grey' or 'RGB' (an alpha channel aside)."""
    return "grey" if raw.shape[-1] < 3 else "RGB"


def read_images(paths, *, threads: int = 2, pixels: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Read N images of equal size and bit depth, decoding on `threads` threads.

    Returns images: (N, H, W, 3) float32 fractions of full range (see read_image), or (N, K, 3)
    when `pixels` ((H, W) bool) is given: only the K pixels where it is True, in row-major order
    (saves memory when only an object mask is needed). Also returns the common bit depth.
    Raises CaptureError naming the first file (in the order given) that is missing or unreadable,
    whose size differs from the first image's (or from `pixels`), or whose bit depth or colour (grey
    among RGB images, or RGB among grey) differs.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise CaptureError("read_images: no image paths given (expected at least one)")
    first_raw, bits = _decode(paths[0])
    shape = first_raw.shape[:2]
    colour = _colour(first_raw)
    if pixels is not None:
        pixels = np.asarray(pixels, dtype=bool)
        if pixels.shape != shape:
            raise CaptureError(
                f"{paths[0]}: image is {_size(shape)}, expected {_size(pixels.shape)} (the size of the pixel mask)"
            )
        flat = np.flatnonzero(pixels.ravel())
        out = np.empty((len(paths), flat.size, 3), dtype=np.float32)
    else:
        flat = None
        out = np.empty((len(paths),) + shape + (3,), dtype=np.float32)

    def convert(i: int, raw: np.ndarray, depth: int) -> None:
        if raw.shape[:2] != shape:
            raise CaptureError(f"{paths[i]} is {_size(raw.shape)}, expected {_size(shape)} like {paths[0]}")
        if depth != bits:
            raise CaptureError(f"{paths[i]} is a {depth}-bit image, expected {bits}-bit like {paths[0]}")
        if _colour(raw) != colour:
            raise CaptureError(
                f"{paths[i]} is a {_colour(raw)} image, expected {colour} like {paths[0]} "
                "(one camera mode for every light)"
            )
        if flat is not None:
            raw = raw.reshape(-1, raw.shape[2])[flat]
        _to_float(raw, depth, out=out[i])

    def job(i: int) -> None:
        raw, depth = _decode(paths[i])
        convert(i, raw, depth)

    convert(0, first_raw, bits)
    del first_raw
    thread_map(job, range(1, len(paths)), threads)  # in path order, so the first bad file is the one reported
    return out, bits


def write_png(path, image, bits: int) -> None:
    """Write an image as an 8- or 16-bit PNG.

    image: (H, W, 3), (H, W, 4) or grey (H, W) / (H, W, 1); either float in [0, 1], stored as
    round(v * (2**bits - 1)), or integers already in the file's sample type (uint8 for bits=8,
    uint16 for bits=16), stored as they are.
    Raises CaptureError naming the file for NaN or out-of-range floats, a sample type that does not
    match `bits`, an unsupported shape, or a file that cannot be written.
    """
    import kornia_rs

    path = Path(path)
    if bits not in (8, 16):
        raise CaptureError(f"{path}: bits={bits!r}, expected 8 or 16")
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4) or img.shape[0] == 0 or img.shape[1] == 0:
        raise CaptureError(
            f"{path}: image of shape {np.asarray(image).shape}, expected (H, W), (H, W, 1), (H, W, 3) or (H, W, 4)"
        )
    dtype = np.uint8 if bits == 8 else np.uint16
    if np.issubdtype(img.dtype, np.floating):
        finite = np.isfinite(img)
        if not finite.all():
            raise CaptureError(
                f"{path}: image has {int((~finite).sum())} NaN or inf values (expected floats in [0, 1])"
            )
        lo, hi = float(img.min()), float(img.max())
        if lo < 0.0 or hi > 1.0:
            raise CaptureError(f"{path}: float image values span [{lo:.6g}, {hi:.6g}], expected [0, 1]")
        img = np.rint(img.astype(np.float64) * (2**bits - 1)).astype(dtype)
    elif img.dtype == np.bool_ or img.dtype != dtype:
        raise CaptureError(
            f"{path}: image of type {img.dtype} cannot be written as a {bits}-bit PNG "
            f"(expected floats in [0, 1] or {np.dtype(dtype).name})"
        )
    img = np.ascontiguousarray(img)
    mode = {1: "mono", 3: "rgb", 4: "rgba"}[img.shape[2]]
    writer = kornia_rs.io.write_image_png_u8 if bits == 8 else kornia_rs.io.write_image_png_u16
    try:
        writer(str(path), img, mode)
    except Exception as exc:
        raise CaptureError(f"{path}: cannot write PNG ({exc})") from None


def image_info(path) -> tuple[int, int, int]:
    """(width, height, bit depth) of an image file from its header, without decoding the pixels. CaptureError
    naming the file when it is missing or not a readable image."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        what = "a folder" if path.is_dir() else "missing"
        raise CaptureError(f"{path}: image file {what}")
    if is_exr(path):
        return (*exr_size(path), EXR_BITS)
    if _png_header(path) is not None:
        with open(path, "rb") as fh:
            head = fh.read(25)
        width, height, bits = struct.unpack(">IIB", head[16:25])
        return width, height, bits
    try:
        with Image.open(path) as im:
            return im.width, im.height, 16 if im.mode in _PIL_16BIT_MODES else 8
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
        raise CaptureError(f"{path}: not a readable image (Pillow: {exc})") from None
