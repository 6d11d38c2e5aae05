"""Image I/O: 16-bit PNGs keep every bit, 8-bit round trips, clear errors naming the file.

The reader is checked against PNGs built byte by byte here (zlib + CRC, no image library), so the
check does not rely on the writer under test; the writer is then checked through the reader and
against Pillow's (8-bit, high byte) view of the files it writes.
"""

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from torchrefl.capture.images import image_info, read_image, read_images, write_png
from torchrefl.errors import CaptureError

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared"
BALL = SHARED / "data" / "diligent_ball"


def raw_png(path: Path, samples: np.ndarray) -> None:
    """Write (H, W, C) uint8/uint16 samples as a PNG by hand (filter 0 on every row, big-endian samples)."""
    samples = np.asarray(samples)
    if samples.ndim == 2:
        samples = samples[..., None]
    H, W, C = samples.shape
    depth = 16 if samples.dtype == np.uint16 else 8
    colour = {1: 0, 2: 4, 3: 2, 4: 6}[C]
    rows = samples.astype(">u2" if depth == 16 else "u1").reshape(H, -1)
    data = b"".join(b"\x00" + row.tobytes() for row in rows)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", W, H, depth, colour, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(data)) + chunk(b"IEND", b"")
    )


def hostile_16bit() -> np.ndarray:
    """(256, 256, 3) uint16: R = every value 0..65535 once, G = 257 k + 1 (never a multiple of 257), B = reversed R."""
    ramp = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    k = np.arange(256 * 256).reshape(256, 256) % 255
    return np.stack([ramp, (257 * k + 1).astype(np.uint16), ramp[::-1, ::-1]], axis=-1)


def as_counts(image: np.ndarray, bits: int) -> np.ndarray:
    return np.rint(image.astype(np.float64) * (2**bits - 1)).astype(np.int64)


def test_reader_keeps_all_16_bits_of_a_hand_made_png(tmp_path):
    v = hostile_16bit()
    raw_png(tmp_path / "h.png", v)
    img, bits = read_image(tmp_path / "h.png")
    assert bits == 16 and img.dtype == np.float32 and img.shape == (256, 256, 3)
    np.testing.assert_array_equal(img, v.astype(np.float32) / np.float32(65535))
    np.testing.assert_array_equal(as_counts(img, 16), v)


def test_reader_grey_and_alpha_layouts(tmp_path):
    g16 = (np.arange(48, dtype=np.uint16) * 1361 + 7).reshape(6, 8)
    raw_png(tmp_path / "g16.png", g16)
    img, bits = read_image(tmp_path / "g16.png")
    assert bits == 16 and img.shape == (6, 8, 3)
    for c in range(3):
        np.testing.assert_array_equal(as_counts(img[..., c], 16), g16)

    rgba = np.concatenate([hostile_16bit()[:5, :7], np.full((5, 7, 1), 123, np.uint16)], axis=-1)
    raw_png(tmp_path / "rgba16.png", rgba)
    img, bits = read_image(tmp_path / "rgba16.png")
    assert bits == 16
    np.testing.assert_array_equal(as_counts(img, 16), rgba[..., :3])

    g8 = (np.arange(48, dtype=np.uint8) * 5).reshape(6, 8)
    raw_png(tmp_path / "g8.png", g8)
    img, bits = read_image(tmp_path / "g8.png")
    assert bits == 8
    np.testing.assert_array_equal(as_counts(img, 8), np.repeat(g8[..., None], 3, axis=-1))

    la = np.stack([g8, np.full_like(g8, 200)], axis=-1)  # grey + alpha: not decoded by kornia_rs
    raw_png(tmp_path / "la8.png", la)
    img, bits = read_image(tmp_path / "la8.png")
    assert bits == 8
    np.testing.assert_array_equal(as_counts(img, 8), np.repeat(g8[..., None], 3, axis=-1))


def test_reader_palette_png_gives_colours_not_indices(tmp_path):
    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[:3] = (200, 10, 30)
    rgb[3:] = (5, 250, 60)
    Image.fromarray(rgb).convert("P", palette=Image.Palette.ADAPTIVE, colors=4).save(tmp_path / "p.png")
    img, bits = read_image(tmp_path / "p.png")
    assert bits == 8
    np.testing.assert_array_equal(as_counts(img, 8), rgb)


def test_write_png_16bit_round_trip_and_pillow_high_byte(tmp_path):
    v = hostile_16bit()
    write_png(tmp_path / "w.png", v, bits=16)
    img, bits = read_image(tmp_path / "w.png")
    assert bits == 16
    np.testing.assert_array_equal(as_counts(img, 16), v)
    # Pillow reduces 16-bit RGB to the high byte: an independent check of byte order and channel order
    high = np.asarray(Image.open(tmp_path / "w.png").convert("RGB")).astype(np.int64)
    assert np.abs(high - (v.astype(np.int64) >> 8)).max() <= 1

    # floats are stored as round(v * 65535)
    f = np.random.default_rng(0).uniform(0, 1, size=(7, 9, 3))
    f[0, 0] = (0.0, 1.0, 0.5 / 65535 + 1e-9)
    write_png(tmp_path / "f.png", f, bits=16)
    img, _ = read_image(tmp_path / "f.png")
    np.testing.assert_array_equal(as_counts(img, 16), np.floor(f * 65535 + 0.5).astype(np.int64))


def test_write_png_8bit_round_trip(tmp_path):
    v = np.random.default_rng(1).integers(0, 256, size=(5, 11, 3)).astype(np.uint8)
    write_png(tmp_path / "u8.png", v, bits=8)
    img, bits = read_image(tmp_path / "u8.png")
    assert bits == 8
    np.testing.assert_array_equal(as_counts(img, 8), v)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "u8.png")), v)

    f = np.linspace(0, 1, 5 * 11 * 3).reshape(5, 11, 3)
    write_png(tmp_path / "f8.png", f, bits=8)
    img, _ = read_image(tmp_path / "f8.png")
    np.testing.assert_array_equal(as_counts(img, 8), np.floor(f * 255 + 0.5).astype(np.int64))

    grey = np.linspace(0, 1, 30).reshape(5, 6)
    write_png(tmp_path / "grey.png", grey, bits=8)
    img, _ = read_image(tmp_path / "grey.png")
    np.testing.assert_array_equal(as_counts(img, 8), np.repeat(np.floor(grey * 255 + 0.5)[..., None], 3, -1))


@pytest.mark.parametrize(
    "bad, what",
    [
        (np.full((3, 4, 3), 1.5), "expected [0, 1]"),
        (np.full((3, 4, 3), -0.1), "expected [0, 1]"),
        (np.full((3, 4, 3), np.nan), "NaN"),
        (np.zeros((3, 4, 3), np.uint16), "8-bit"),  # uint16 samples for an 8-bit file
        (np.zeros((3, 4, 2)), "expected (H, W)"),
    ],
)
def test_write_png_rejects_bad_images(tmp_path, bad, what):
    with pytest.raises(CaptureError) as err:
        write_png(tmp_path / "bad.png", bad, bits=8)
    assert "bad.png" in str(err.value) and what in str(err.value)
    assert not (tmp_path / "bad.png").exists()


def test_write_png_unwritable_path(tmp_path):
    with pytest.raises(CaptureError, match="no_such_dir"):
        write_png(tmp_path / "no_such_dir" / "x.png", np.zeros((2, 2, 3)), bits=8)


def test_read_errors_name_the_file(tmp_path):
    with pytest.raises(CaptureError, match="missing.png.*missing"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)
    with pytest.raises(CaptureError, match="corrupt.png"):
        read_image(tmp_path / "corrupt.png")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(CaptureError, match="empty.png"):
        read_image(tmp_path / "empty.png")
    # a valid header with truncated image data
    raw_png(tmp_path / "whole.png", hostile_16bit()[:20, :20])
    data = (tmp_path / "whole.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(CaptureError, match="cut.png"):
        read_image(tmp_path / "cut.png")
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(CaptureError, match="text.png"):
        read_image(tmp_path / "text.png")


def test_unsupported_depth_names_the_file(tmp_path):
    import kornia_rs

    kornia_rs.io.write_image_tiff_f32(str(tmp_path / "float.tiff"), np.zeros((4, 5, 3), np.float32), "rgb")
    with pytest.raises(CaptureError, match="float.tiff.*float32"):
        read_image(tmp_path / "float.tiff")


def test_read_images_stacks_in_order_and_selects_pixels(tmp_path):
    rng = np.random.default_rng(2)
    stack = rng.integers(0, 65536, size=(5, 6, 8, 3)).astype(np.uint16)
    paths = []
    for i, s in enumerate(stack):
        paths.append(tmp_path / f"{i:03d}.png")
        raw_png(paths[-1], s)
    for threads in (1, 3):
        images, bits = read_images(paths, threads=threads)
        assert bits == 16 and images.shape == (5, 6, 8, 3) and images.dtype == np.float32
        np.testing.assert_array_equal(as_counts(images, 16), stack)
    mask = rng.uniform(size=(6, 8)) > 0.5
    sel, _ = read_images(paths, threads=2, pixels=mask)
    assert sel.shape == (5, int(mask.sum()), 3)
    np.testing.assert_array_equal(as_counts(sel, 16), stack[:, mask])
    with pytest.raises(CaptureError, match="000.png.*8x6.*pixel mask"):
        read_images(paths, pixels=np.ones((3, 3), bool))


def test_read_images_names_the_first_mismatching_file(tmp_path):
    paths = [tmp_path / f"{i:03d}.png" for i in range(1, 6)]
    for p in paths:
        raw_png(p, np.zeros((80, 100, 3), np.uint16))
    raw_png(paths[2], np.zeros((81, 100, 3), np.uint16))
    raw_png(paths[4], np.zeros((80, 99, 3), np.uint16))
    for threads in (1, 2):
        with pytest.raises(CaptureError) as err:
            read_images(paths, threads=threads)
        msg = str(err.value)
        assert "003.png is 100x81" in msg and "expected 100x80 like" in msg and "001.png" in msg
    raw_png(paths[2], np.zeros((80, 100, 3), np.uint16))
    raw_png(paths[3], np.zeros((80, 100, 3), np.uint8))
    with pytest.raises(CaptureError, match="004.png is a 8-bit image, expected 16-bit"):
        read_images(paths)
    paths[1].unlink()
    with pytest.raises(CaptureError, match="002.png"):
        read_images(paths)


@pytest.mark.skipif(not BALL.is_dir(), reason="../shared/data/diligent_ball missing")
def test_diligent_ball_image_is_read_at_16_bits():
    img, bits = read_image(BALL / "001.png")
    assert bits == 16 and img.shape == (512, 612, 3)
    v = as_counts(img, 16)
    assert (v % 257 != 0).sum() > 1000  # an 8-bit value scaled to 16 bits would be a multiple of 257
    # byte and channel order: the high byte equals Pillow's 8-bit reading of the same file
    pil = np.asarray(Image.open(BALL / "001.png").convert("RGB")).astype(np.int64)
    assert np.abs((v >> 8) - pil).max() <= 1


def test_image_info_reads_size_and_depth_from_the_header(tmp_path):
    write_png(tmp_path / "a.png", np.zeros((5, 7, 3), dtype=np.uint16), 16)
    write_png(tmp_path / "b.png", np.zeros((4, 3), dtype=np.uint8), 8)
    Image.new("RGB", (9, 2)).save(tmp_path / "c.jpg")
    assert image_info(tmp_path / "a.png") == (7, 5, 16)
    assert image_info(tmp_path / "b.png") == (3, 4, 8)
    assert image_info(tmp_path / "c.jpg") == (9, 2, 8)
    (tmp_path / "d.png").write_bytes(b"not an image")
    with pytest.raises(CaptureError, match=r"d\.png: not a readable image"):
        image_info(tmp_path / "d.png")
    with pytest.raises(CaptureError, match=r"e\.png: image file missing"):
        image_info(tmp_path / "e.png")
