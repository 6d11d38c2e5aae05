"""cameras.json: a hand-written file read into Cameras; malformed files are errors naming the file and key."""

import pytest

from torchrefl.capture.cameras_json import read_cameras_json
from torchrefl.errors import CaptureError

CAM = {
    "width": 64,
    "height": 48,
    "fx": 50.0,
    "fy": 52.0,
    "cx": 31.5,
    "cy": 23.5,
    "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
    "t": [0, 0, 100],
}


def test_reads_cameras_in_file_order_with_distortion_defaults(write_json):
    doc = {"right": dict(CAM, k1=0.1, p2=-0.01), "left": dict(CAM, t=[5, 0, 100])}
    cams = read_cameras_json(write_json("cameras.json", doc))
    assert cams.names == ("right", "left")
    assert cams.width.tolist() == [64, 64] and cams.height.tolist() == [48, 48]
    assert cams.K[0].tolist() == [[50.0, 0.0, 31.5], [0.0, 52.0, 23.5], [0.0, 0.0, 1.0]]
    assert cams.distortion.tolist() == [[0.1, 0.0, 0.0, -0.01, 0.0], [0.0] * 5]
    assert cams.t[1].tolist() == [5.0, 0.0, 100.0]
    assert cams.centres()[1].tolist() == [-5.0, 0.0, -100.0]


@pytest.mark.parametrize(
    "camera, message",
    [
        ({k: v for k, v in CAM.items() if k != "fx"}, r"missing key \['c'\]\.fx"),
        (dict(CAM, fov=3), r"unknown key \['c'\]\.fov"),
        (dict(CAM, width=64.5), r"\['c'\]\.width must be a positive integer"),
        ('{"c": {"width": 1e400}}', r"\['c'\]\.width must be a positive integer"),
        (dict(CAM, fy="52"), r"\['c'\]\.fy must be a finite number"),
        (dict(CAM, R=[[1, 0, 0], [0, 1, 0]]), r"\['c'\]\.R must be 3 x 3 finite numbers"),
        (dict(CAM, t=[0, 0]), r"\['c'\]\.t must be 3 finite numbers"),
        (dict(CAM, R=[[1, 0, 0], [0, 2, 0], [0, 0, 1]]), "camera 'c': R is not orthonormal"),
        (dict(CAM, fx=0), "camera 'c': focal length fx = 0.0"),
    ],
)
def test_bad_camera_names_file_and_key(write_json, camera, message):
    path = write_json("cameras.json", camera if isinstance(camera, str) else {"c": camera})
    with pytest.raises(CaptureError, match=rf"cameras\.json.*{message}"):
        read_cameras_json(path)


@pytest.mark.parametrize(
    "text, message",
    [
        ('{"c": {"width": 64,}}', "not valid JSON at line 1, column 20"),
        ('{"c": {"width": NaN}}', "NaN is not a finite number"),
        ("[1, 2]", "the document must be a JSON object"),
        ("{}", "no camera"),
    ],
)
def test_malformed_file_is_named(write_json, text, message):
    with pytest.raises(CaptureError, match=rf"cameras\.json: {message}"):
        read_cameras_json(write_json("cameras.json", text))


def test_missing_file_is_named(tmp_path):
    with pytest.raises(CaptureError, match=r"cameras\.json: file missing"):
        read_cameras_json(tmp_path / "cameras.json")
