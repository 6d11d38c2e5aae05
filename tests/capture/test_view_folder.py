"""A mesh_views folder's metadata: pairing of images with cameras and lights, image sizes, encodings."""

import json

import numpy as np
import pytest

from torchrefl.capture.images import write_png
from torchrefl.capture.view_folder import read_view_folder
from torchrefl.errors import CaptureError

W, H = 8, 6
CAMERA = {"width": W, "height": H, "fx": 10.0, "fy": 10.0, "cx": 3.5, "cy": 2.5, "t": [0, 0, 50]}
EYE = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]


def make_folder(tmp_path, images=None, encoding="linear", bits=16, **top):
    folder = tmp_path / "capture"
    (folder / "img").mkdir(parents=True)
    cameras = {"c0": dict(CAMERA, R=EYE), "c1": dict(CAMERA, R=EYE, t=[10, 0, 50])}
    (folder / "cameras.json").write_text(json.dumps(cameras))
    lights = {"l0": {"position": [0, 0, -100], "intensity": 1e4}, "l1": {"direction": [0, 0, -1], "intensity": 1}}
    (folder / "lights.json").write_text(json.dumps(lights))
    if images is None:
        images = [
            {"file": "img/a.png", "camera": "c0", "light": "l0"},
            {"file": "img/b.png", "camera": "c1", "light": "l0", "mask": "img/m.png"},
        ]
    for name in ("a", "b", "m"):
        value = np.full((H, W, 3), 30000 if bits == 16 else 128, dtype=np.uint16 if bits == 16 else np.uint8)
        write_png(folder / "img" / f"{name}.png", value, bits)
    (folder / "images.json").write_text(json.dumps(dict(encoding=encoding, images=images, **top)))
    return folder


def test_reads_and_pairs(tmp_path):
    view = read_view_folder(make_folder(tmp_path))
    assert view.camera_index.tolist() == [0, 1] and view.light_index.tolist() == [0, 0]
    assert [p.name for p in view.paths] == ["a.png", "b.png"] and view.masks[0] is None
    assert view.bits == 16
    assert view.warnings == (f"1 light(s) that no image of {view.views.source} uses, e.g. 'l1'",)
    assert view.read_image(0)[0, 0].tolist() == pytest.approx([30000 / 65535] * 3)
    assert view.read_mask(1).all() and view.read_mask(0) is None


def test_srgb_images_are_decoded_by_the_srgb_curve(tmp_path):
    view = read_view_folder(make_folder(tmp_path, encoding="srgb", bits=8))
    expected = ((128 / 255 + 0.055) / 1.055) ** 2.4
    assert view.read_image(0)[0, 0].tolist() == pytest.approx([expected] * 3, rel=1e-6)


def test_srgb_with_16_bit_images_is_an_error(tmp_path):
    with pytest.raises(CaptureError, match="encoding is srgb, but the images are 16-bit"):
        read_view_folder(make_folder(tmp_path, encoding="srgb", bits=16))


@pytest.mark.parametrize(
    "image, message",
    [
        ({"file": "img/a.png", "camera": "c9", "light": "l0"}, r"\.images\[0\] names camera 'c9'.*cameras\.json"),
        ({"file": "img/a.png", "camera": "c0", "light": "l9"}, r"\.images\[0\] names light 'l9'.*lights\.json"),
        ({"file": "img/z.png", "camera": "c0", "light": "l0"}, r"\.images\[0\]\.file: image file .*z\.png is missing"),
        (
            {"file": "img/a.png", "camera": "c0", "light": "l0", "mask": "n.png"},
            r"\.images\[0\]\.mask: mask file .*missing",
        ),
    ],
)
def test_pairing_names_the_missing_camera_light_or_file(tmp_path, image, message):
    with pytest.raises(CaptureError, match=rf"images\.json: {message}"):
        read_view_folder(make_folder(tmp_path, images=[image]))


def test_image_size_must_be_the_cameras(tmp_path):
    folder = make_folder(tmp_path)
    write_png(folder / "img" / "b.png", np.zeros((H, W + 1, 3), dtype=np.uint16), 16)
    with pytest.raises(CaptureError, match=r"\.images\[1\]\.file: .*b\.png is 9x6 pixels, but its camera 'c1' is 8x6"):
        read_view_folder(folder)
    folder = make_folder(tmp_path / "again")
    write_png(folder / "img" / "m.png", np.zeros((H + 1, W), dtype=np.uint8), 8)
    with pytest.raises(CaptureError, match=r"\.images\[1\]\.mask: .*m\.png is 8x7 pixels"):
        read_view_folder(folder)


def test_one_file_twice_and_mixed_bit_depths_are_errors(tmp_path):
    twice = [{"file": "img/a.png", "camera": "c0", "light": "l0"}, {"file": "img/a.png", "camera": "c1", "light": "l0"}]
    with pytest.raises(CaptureError, match=r"\.images\[1\]\.file: .*a\.png is also \.images\[0\]'s file"):
        read_view_folder(make_folder(tmp_path, images=twice))
    folder = make_folder(tmp_path / "again")
    write_png(folder / "img" / "b.png", np.zeros((H, W, 3), dtype=np.uint8), 8)
    with pytest.raises(CaptureError, match=r"\.images\[1\]\.file: .*b\.png is a 8-bit image, expected 16-bit"):
        read_view_folder(folder)


def test_colmap_model_missing_the_named_image(tmp_path):
    folder = make_folder(tmp_path, images=[{"file": "img/a.png", "camera": "img/b.png", "light": "l0"}], cameras="sp")
    (folder / "sp").mkdir()
    (folder / "sp" / "cameras.txt").write_text(f"1 PINHOLE {W} {H} 10 10 4 3\n")
    (folder / "sp" / "images.txt").write_text("1 1 0 0 0 0 0 50 1 img/a.png\n\n")
    with pytest.raises(CaptureError, match=r"names camera 'img/b\.png', but the COLMAP model .*sp has no image named"):
        read_view_folder(folder)
    (folder / "images.json").write_text(
        json.dumps({"encoding": "linear", "cameras": "sp", "images": [{"file": "img/a.png", "camera": "img/a.png",
                                                                       "light": "l0"}]})
    )  # fmt: skip
    view = read_view_folder(folder)
    assert view.cameras.names == ("img/a.png",) and view.cameras.cx.tolist() == [3.5]


def test_cameras_neither_json_nor_model_folder(tmp_path):
    with pytest.raises(CaptureError, match=r"\.cameras is 'cams\.yaml'.*neither a \.json file nor a folder"):
        read_view_folder(make_folder(tmp_path, cameras="cams.yaml"))


def test_exr_images_are_read_as_linear_floats(tmp_path):
    """A folder of OpenEXR photographs (written by the openexr package's own writer): sizes checked against the
    camera, samples returned as they are."""
    OpenEXR = pytest.importorskip("OpenEXR")
    images = [
        {"file": "img/a.exr", "camera": "c0", "light": "l0"},
        {"file": "img/b.exr", "camera": "c1", "light": "l1"},
    ]
    folder = make_folder(tmp_path, images=images)
    rgb = np.random.default_rng(0).uniform(0, 1.2, size=(2, H, W, 3)).astype(np.float32)
    for k, name in enumerate("ab"):
        channels = {c: np.ascontiguousarray(rgb[k, ..., j]) for j, c in enumerate("RGB")}
        with OpenEXR.File({}, channels) as f:
            f.write(str(folder / "img" / f"{name}.exr"))
    view = read_view_folder(folder)
    assert view.bits == 32
    np.testing.assert_array_equal(view.read_image(1), rgb[1])
    with OpenEXR.File({}, {"Y": np.zeros((H, W + 1), np.float32)}) as f:
        f.write(str(folder / "img" / "b.exr"))
    with pytest.raises(CaptureError, match=rf"b\.exr is {W + 1}x{H} pixels, but its camera 'c1' is {W}x{H}"):
        read_view_folder(folder)
