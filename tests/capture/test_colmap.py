"""COLMAP models written by pycolmap (text and binary, five camera models) read into Cameras: the same cameras
as the equivalent cameras.json, reprojection within 1e-6 px of pycolmap's own projection, the pixel-centre
shift, and the named errors."""

import json

import numpy as np
import pycolmap
import pytest
import torch

from torchrefl.capture.cameras_json import read_cameras_json
from torchrefl.capture.colmap import read_colmap_model
from torchrefl.errors import CaptureError

WIDTH, HEIGHT = 640, 480
#: model -> (COLMAP params, the cameras.json intrinsics written by hand: COLMAP's cx, cy minus 0.5)
MODELS = {
    "SIMPLE_PINHOLE": ([700.0, 320.5, 240.5], dict(fx=700.0, fy=700.0, cx=320.0, cy=240.0)),
    "PINHOLE": ([700.0, 720.0, 300.25, 250.75], dict(fx=700.0, fy=720.0, cx=299.75, cy=250.25)),
    "SIMPLE_RADIAL": ([700.0, 320.5, 240.5, -0.08], dict(fx=700.0, fy=700.0, cx=320.0, cy=240.0, k1=-0.08)),
    "RADIAL": ([700.0, 320.5, 240.5, -0.08, 0.02], dict(fx=700.0, fy=700.0, cx=320.0, cy=240.0, k1=-0.08, k2=0.02)),
    "OPENCV": (
        [700.0, 720.0, 310.0, 230.0, -0.08, 0.02, 0.001, -0.002],
        dict(fx=700.0, fy=720.0, cx=309.5, cy=229.5, k1=-0.08, k2=0.02, p1=0.001, p2=-0.002),
    ),
}
#: two images: (name, axis-angle, t) world-to-camera
POSES = [("img_a.png", [0.1, -0.2, 0.05], [1.0, -2.0, 40.0]), ("sub/img_b.png", [-0.3, 0.4, 0.2], [-3.0, 1.0, 45.0])]


def write_model(folder, model, params, binary):
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera(model=model, width=WIDTH, height=HEIGHT, params=params, camera_id=1)
    )
    for image_id, (name, axis_angle, t) in enumerate(POSES, start=1):
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array(axis_angle)), np.array(t))
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=image_id), pose)
    folder.mkdir(parents=True)
    (rec.write_binary if binary else rec.write_text)(str(folder))
    return rec


def equivalent_cameras_json(path, rec, intrinsics):
    doc = {}
    for image_id in sorted(rec.images):
        image = rec.image(image_id)
        matrix = image.cam_from_world().matrix()
        doc[image.name] = dict(width=WIDTH, height=HEIGHT, R=matrix[:, :3].tolist(), t=matrix[:, 3].tolist())
        doc[image.name].update(intrinsics)
    path.write_text(json.dumps(doc))
    return read_cameras_json(path)


def points_in_view():
    rng = np.random.default_rng(7)
    return rng.uniform([-8, -6, -5], [8, 6, 5], size=(50, 3))


@pytest.mark.parametrize("binary", [False, True], ids=["text", "binary"])
@pytest.mark.parametrize("model", list(MODELS))
def test_pycolmap_model_loads_to_the_equivalent_cameras_json(tmp_path, model, binary):
    params, intrinsics = MODELS[model]
    rec = write_model(tmp_path / "sparse", model, params, binary)
    assert (tmp_path / "sparse" / ("cameras.bin" if binary else "cameras.txt")).is_file()
    cams = read_colmap_model(tmp_path / "sparse")
    reference = equivalent_cameras_json(tmp_path / "cameras.json", rec, intrinsics)
    assert cams.names == ("img_a.png", "sub/img_b.png") == reference.names
    points = points_in_view()
    uv = cams.project(torch.as_tensor(points)).uv
    assert torch.allclose(uv, reference.project(torch.as_tensor(points)).uv, atol=1e-6, rtol=0)
    camera = rec.camera(1)
    for i, image_id in enumerate(sorted(rec.images)):
        pose = rec.image(image_id).cam_from_world().matrix()
        colmap_uv = camera.img_from_cam(points @ pose[:, :3].T + pose[:, 3])
        # pycolmap's own projection, moved from COLMAP's pixel centres (0.5) to torchrefl's (0)
        assert np.abs(uv[i].numpy() - (colmap_uv - 0.5)).max() < 1e-6


def test_colmap_pixel_half_is_our_pixel_zero(tmp_path):
    params = MODELS["OPENCV"][0]
    rec = write_model(tmp_path / "sparse", "OPENCV", params, binary=False)
    xy = rec.camera(1).cam_from_img(np.array([[0.5, 0.5]]))[0]  # the ray through COLMAP's pixel (0.5, 0.5)
    pose = rec.image(1).cam_from_world().matrix()
    world = pose[:, :3].T @ (np.array([xy[0], xy[1], 1.0]) * 30.0 - pose[:, 3])
    uv = read_colmap_model(tmp_path / "sparse").project(torch.as_tensor(world[None]), camera=0).uv[0]
    assert uv.tolist() == pytest.approx([0.0, 0.0], abs=1e-6)


def test_text_model_with_points_lines_and_comments(tmp_path):
    folder = tmp_path / "m"
    folder.mkdir()
    (folder / "cameras.txt").write_text("# comment\n7 PINHOLE 100 80 90 91 50.5 40.5\n")
    (folder / "images.txt").write_text(
        "# header\n3 1 0 0 0 0 0 10 7 b.png\n1.0 2.0 -1 3.0 4.0 5\n1 1 0 0 0 1 2 10 7 a.png\n\n"
    )
    cams = read_colmap_model(folder)
    assert cams.names == ("a.png", "b.png")  # image-id order
    assert cams.t.tolist() == [[1.0, 2.0, 10.0], [0.0, 0.0, 10.0]]
    assert cams.K[0].tolist() == [[90.0, 0.0, 50.0], [0.0, 91.0, 40.0], [0.0, 0.0, 1.0]]


@pytest.mark.parametrize("binary", [False, True], ids=["text", "binary"])
def test_unsupported_camera_model_lists_the_supported_ones(tmp_path, binary):
    write_model(tmp_path / "sparse", "OPENCV_FISHEYE", [700.0, 700.0, 320.0, 240.0, 0.1, 0, 0, 0], binary)
    with pytest.raises(CaptureError, match="OPENCV_FISHEYE is not supported.*SIMPLE_PINHOLE, PINHOLE"):
        read_colmap_model(tmp_path / "sparse")


def test_truncated_binary_model_is_named(tmp_path):
    write_model(tmp_path / "sparse", "PINHOLE", MODELS["PINHOLE"][0], binary=True)
    images = tmp_path / "sparse" / "images.bin"
    images.write_bytes(images.read_bytes()[:-10])
    with pytest.raises(CaptureError, match=r"images\.bin.*truncated"):
        read_colmap_model(tmp_path / "sparse")


def test_incomplete_model_and_unknown_camera_are_named(tmp_path):
    folder = tmp_path / "m"
    folder.mkdir()
    (folder / "cameras.txt").write_text("1 PINHOLE 100 80 90 91 50 40\n")
    with pytest.raises(CaptureError, match="no complete COLMAP model.*found cameras.txt"):
        read_colmap_model(folder)
    (folder / "images.txt").write_text("1 1 0 0 0 0 0 10 2 a.png\n\n")
    with pytest.raises(CaptureError, match="uses camera 2"):
        read_colmap_model(folder)
    (folder / "images.txt").write_text("1 2 0 0 0 0 0 10 1 a.png\n\n")
    with pytest.raises(CaptureError, match="unit quaternion"):
        read_colmap_model(folder)
