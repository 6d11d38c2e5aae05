"""OpenEXR images: the reader returns the samples the openexr package's own writer stored, and names the file
for every layout it refuses."""

import sys

import numpy as np
import pytest

from torchrefl.capture.images import image_info, read_image, read_images
from torchrefl.errors import CaptureError, MissingPackageError

OpenEXR = pytest.importorskip("OpenEXR")


def write_exr(path, channels: dict, **header) -> None:
    """channels: name -> (H, W) float16 / float32 / uint32 array, written by OpenEXR's own writer (which reads the
    arrays' memory as C-contiguous, so they are made so)."""
    channels = {k: np.ascontiguousarray(v) for k, v in channels.items()}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, **header}, channels) as f:
        f.write(str(path))


def test_float_rgb_samples_come_back_exactly(tmp_path):
    rng = np.random.default_rng(3)
    rgb = rng.uniform(-0.01, 1.3, size=(5, 7, 3)).astype(np.float32)  # linear values, a little noise below 0
    write_exr(tmp_path / "a.exr", {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})
    image, bits = read_image(tmp_path / "a.exr")
    assert bits == 32 and image.dtype == np.float32 and image.shape == (5, 7, 3)
    np.testing.assert_array_equal(image, rgb)
    assert image_info(tmp_path / "a.exr") == (7, 5, 32)


def test_half_grey_with_alpha_is_three_equal_channels(tmp_path):
    grey = np.array([[0.0, 0.25, 0.5], [0.75, 1.0, 0.125]], dtype=np.float16)
    write_exr(tmp_path / "g.exr", {"Y": grey, "A": np.ones_like(grey)})
    image, _ = read_image(tmp_path / "g.exr")
    np.testing.assert_array_equal(image, np.repeat(grey.astype(np.float32)[..., None], 3, axis=-1))


def test_several_exr_files_and_a_png_among_them(tmp_path):
    from torchrefl.capture.images import write_png

    ones = np.ones((2, 3), dtype=np.float32)
    for k in range(2):
        write_exr(tmp_path / f"{k}.exr", {"R": ones * k, "G": ones, "B": ones / 4})
    images, bits = read_images([tmp_path / "0.exr", tmp_path / "1.exr"])
    assert bits == 32 and images[1, 0, 0].tolist() == [1.0, 1.0, 0.25]
    write_png(tmp_path / "p.png", np.zeros((2, 3, 3), dtype=np.uint16), bits=16)
    with pytest.raises(CaptureError, match=r"p\.png is a 16-bit image, expected 32-bit"):
        read_images([tmp_path / "0.exr", tmp_path / "p.png"])


@pytest.mark.parametrize(
    "channels, message",
    [
        ({"diffuse.R": np.zeros((2, 2), np.float32)}, r"channels diffuse\.R, expected R, G, B or Y"),
        ({"R": np.zeros((2, 2), np.float32), "G": np.zeros((2, 2), np.float32)}, "channels G, R, expected"),
        ({"Y": np.zeros((2, 2), np.uint32)}, "channel Y holds uint32 samples, expected HALF or FLOAT"),
        ({"Y": np.array([[0.0, np.nan], [np.inf, 1.0]], np.float32)}, "2 NaN or infinite samples"),
    ],
)
def test_refused_layouts_name_the_file(tmp_path, channels, message):
    write_exr(tmp_path / "bad.exr", channels)
    with pytest.raises(CaptureError, match=rf"bad\.exr: .*{message}"):
        read_image(tmp_path / "bad.exr")


def test_damaged_file_is_a_capture_error(tmp_path):
    write_exr(tmp_path / "t.exr", {"Y": np.ones((8, 8), np.float32)})
    (tmp_path / "cut.exr").write_bytes((tmp_path / "t.exr").read_bytes()[:40])
    with pytest.raises(CaptureError, match=r"cut\.exr: not a readable OpenEXR image"):
        read_image(tmp_path / "cut.exr")


def test_without_the_package_the_error_names_file_and_install(tmp_path, monkeypatch):
    write_exr(tmp_path / "a.exr", {"Y": np.ones((2, 2), np.float32)})
    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # import OpenEXR now raises ImportError
    with pytest.raises(MissingPackageError, match=r"a\.exr: reading an OpenEXR image needs .*pip install openexr"):
        read_image(tmp_path / "a.exr")
