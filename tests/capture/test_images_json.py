"""images.json: the document's shape, defaults and named errors."""

import pytest

from torchrefl.capture.images_json import ViewImage, read_images_json
from torchrefl.errors import CaptureError


def test_images_with_defaults_and_folder_keys(write_json):
    doc = {
        "encoding": "srgb",
        "saturation_level": 0.98,
        "kappa": 3.0,
        "cameras": "sparse/0",
        "images": [
            {"file": "a.png", "camera": "c0", "light": "l0"},
            {"file": "b.png", "camera": "c0", "light": "l1", "exposure": 2.5, "mask": "m.png"},
        ],
    }
    views = read_images_json(write_json("images.json", doc))
    assert views.images == (ViewImage("a.png", "c0", "l0"), ViewImage("b.png", "c0", "l1", 2.5, "m.png"))
    assert (views.encoding, views.saturation_level, views.cameras) == ("srgb", 0.98, "sparse/0")
    assert views.kappa.tolist() == [3.0, 3.0, 3.0]
    bare = read_images_json(write_json("images.json", {"encoding": "linear", "images": doc["images"][:1]}))
    assert (bare.saturation_level, bare.kappa, bare.cameras) == (None, None, "cameras.json")


IMAGE = {"file": "a.png", "camera": "c0", "light": "l0"}


@pytest.mark.parametrize(
    "doc, message",
    [
        ({"images": [IMAGE]}, r"missing key \.encoding"),
        ({"encoding": "gamma", "images": [IMAGE]}, r"\.encoding is .gamma., expected one of linear, srgb"),
        ({"encoding": "linear", "images": []}, r"\.images must be a non-empty list"),
        ({"encoding": "linear", "images": [IMAGE], "saturation_level": 1.5}, r"\.saturation_level = 1\.5"),
        ({"encoding": "linear", "images": [IMAGE], "gain": 2}, r"unknown key \.gain"),
        ({"encoding": "linear", "images": [dict(IMAGE, light="")]}, r"\.images\[0\]\.light must be a non-empty"),
        ({"encoding": "linear", "images": [{"file": "a.png", "camera": "c0"}]}, r"missing key \.images\[0\]\.light"),
        ({"encoding": "linear", "images": [dict(IMAGE, exposure=0)]}, r"\.images\[0\]\.exposure must be > 0"),
        ({"encoding": "linear", "images": [dict(IMAGE, lamp="l0")]}, r"unknown key \.images\[0\]\.lamp"),
    ],
)
def test_bad_document_names_file_and_key(write_json, doc, message):
    with pytest.raises(CaptureError, match=rf"images\.json: {message}"):
        read_images_json(write_json("images.json", doc))
