"""Cameras: OpenCV projection checked against hand computations and kornia, centres, in_frame, validation."""

import math

import numpy as np
import pytest
import torch
from kornia.geometry.calibration import distort_points

from torchrefl.capture.cameras import Cameras
from torchrefl.errors import CaptureError

# a 90 degree turn: camera x = -world z, camera y = world y, camera z = world x (looks along world +x)
TURN = [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]


def one_camera(R=TURN, t=(0.0, 0.0, 400.0), fx=1000.0, fy=1100.0, cx=320.0, cy=240.0, dist=(0, 0, 0, 0, 0)):
    return Cameras.from_arrays(["cam"], [640], [480], [fx], [fy], [cx], [cy], [dist], [R], [t], source="test")


def test_pinhole_projection_at_a_known_pose():
    cams = one_camera()
    # world (0, 30, -20) -> camera (20, 30, 0) + t = (20, 30, 400)
    proj = cams.project(torch.tensor([[0.0, 30.0, -20.0]], dtype=torch.float64), camera=0)
    assert proj.uv[0].tolist() == pytest.approx([1000.0 * 20 / 400 + 320, 1100.0 * 30 / 400 + 240], abs=1e-9)
    assert float(proj.depth[0]) == pytest.approx(400.0)


def test_centre_is_minus_r_transpose_t():
    # camera centre C: R C + t = 0; with TURN, C = (-400, 0, 0) gives t = (0, 0, 400)
    assert one_camera().centres()[0].tolist() == pytest.approx([-400.0, 0.0, 0.0], abs=1e-12)


def test_distortion_k1_p1_by_hand():
    k1, p1 = 0.1, 0.01
    cams = one_camera(R=np.eye(3), t=(0.0, 0.0, 0.0), dist=(k1, 0, p1, 0, 0))
    x, y = 0.05, 0.075  # the point (5, 7.5, 100) on the normalised plane
    r2 = x * x + y * y
    xd = x * (1 + k1 * r2) + 2 * p1 * x * y
    yd = y * (1 + k1 * r2) + p1 * (r2 + 2 * y * y)
    uv = cams.project(torch.tensor([[5.0, 7.5, 100.0]], dtype=torch.float64), camera=0).uv[0]
    assert uv.tolist() == pytest.approx([1000.0 * xd + 320.0, 1100.0 * yd + 240.0], abs=1e-9)


def test_all_coefficients_agree_with_kornia():
    rng = np.random.default_rng(3)
    n = 4
    R = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    R *= np.linalg.det(R)[:, None, None]  # proper rotations
    dist = rng.normal(scale=[0.1, 0.05, 0.005, 0.005, 0.01], size=(n, 5))
    cams = Cameras.from_arrays(
        list("abcd"), [800] * n, [600] * n, rng.uniform(500, 900, n), rng.uniform(500, 900, n),
        rng.uniform(350, 450, n), rng.uniform(250, 350, n), dist, R, rng.normal(size=(n, 3)) + [0, 0, 50], "test",
    )  # fmt: skip
    points = torch.as_tensor(rng.normal(scale=5.0, size=(200, 3)))
    uv = cams.project(points).uv
    cam = torch.einsum("nij,pj->npi", cams.R, points) + cams.t[:, None]
    pinhole = (
        cam[..., :2] / cam[..., 2:] * torch.stack([cams.fx, cams.fy], -1)[:, None]
        + torch.stack([cams.cx, cams.cy], -1)[:, None]
    )
    expected = distort_points(pinhole, cams.K, cams.distortion)
    assert torch.allclose(uv, expected, atol=1e-9, rtol=0)


def test_behind_the_camera_is_nan_and_in_frame_bounds():
    cams = one_camera(R=np.eye(3), t=(0.0, 0.0, 0.0))
    proj = cams.project(torch.tensor([[0.0, 0.0, -5.0], [0.0, 0.0, 5.0]], dtype=torch.float64))
    assert torch.isnan(proj.uv[0, 0]).all() and proj.depth[0, 0] == -5.0
    assert proj.uv[0, 1].tolist() == [320.0, 240.0]
    uv = torch.tensor([[[-0.5, -0.5], [639.5, 479.5], [-0.6, 0.0], [0.0, 479.6], [torch.nan, 1.0]]])
    assert cams.in_frame(uv).tolist() == [[True, True, False, False, False]]
    assert cams.in_frame(uv[0], camera=0).tolist() == [True, True, False, False, False]


def test_float32_bulk_matches_float64_and_is_chunked(monkeypatch):
    import torchrefl.capture.cameras as module

    monkeypatch.setattr(module, "CHUNK_PAIRS", 64)  # many chunks for 2 cameras x 500 points
    rng = np.random.default_rng(0)
    cams = Cameras.from_arrays(
        ["a", "b"], [640] * 2, [480] * 2, [900.0] * 2, [900.0] * 2, [320.0] * 2, [240.0] * 2,
        [[0.05, 0.01, 0.001, -0.001, 0.0]] * 2, [np.eye(3), TURN], [[0, 0, 300.0], [0, 0, 300.0]], "test",
    )  # fmt: skip
    points = torch.as_tensor(rng.normal(scale=30.0, size=(500, 3)))
    full = cams.project(points)
    single = cams.project(points.float())
    assert single.uv.dtype == torch.float32
    assert torch.allclose(single.uv.double(), full.uv, atol=1e-2)
    assert torch.equal(cams.project(points, camera=1).uv, full.uv[1])


def test_nearly_orthonormal_r_is_made_a_rotation():
    R = np.array(TURN) + 1e-6
    cams = one_camera(R=R)
    assert torch.allclose(cams.R[0].T @ cams.R[0], torch.eye(3, dtype=torch.float64), atol=1e-12)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"R": [[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}, "not orthonormal"),
        ({"R": [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}, "reflection"),
        ({"fx": 0.0}, "focal length"),
        ({"fy": -3.0}, "focal length"),
        ({"t": (0.0, math.nan, 1.0)}, "t is not finite"),
    ],
)
def test_bad_camera_is_a_named_error(change, message):
    with pytest.raises(CaptureError, match=rf"test: camera 'cam'.*{message}"):
        one_camera(**change)


def test_repeated_name_is_an_error():
    with pytest.raises(CaptureError, match="'a' used twice"):
        Cameras.from_arrays(["a", "a"], [4, 4], [4, 4], [1, 1], [1, 1], [0, 0], [0, 0], np.zeros((2, 5)),
                            [np.eye(3)] * 2, np.zeros((2, 3)), "test")  # fmt: skip


def test_points_beyond_the_distortion_turning_radius_are_left_out():
    # r (1 - 0.5 r^2) stops growing at r^2 = 2/3: beyond it the model folds back towards the centre
    cams = one_camera(R=np.eye(3), t=(0.0, 0.0, 0.0), dist=(-0.5, 0, 0, 0, 0))
    assert cams.max_radius2().tolist() == pytest.approx([2 / 3])
    uv = cams.project(torch.tensor([[0.5, 0.0, 1.0], [1.0, 0.0, 1.0]], dtype=torch.float64), camera=0).uv
    assert uv[0].tolist() == pytest.approx([1000.0 * 0.5 * (1 - 0.5 * 0.25) + 320.0, 240.0])
    assert torch.isnan(uv[1]).all()  # it would land at u = 820, inside the image, without the guard
    assert one_camera(dist=(0.1, 0.01, 0, 0, 0)).max_radius2().tolist() == [math.inf]


def test_skewed_intrinsic_matrix_is_an_error():
    cams = one_camera()
    K = cams.K.clone()
    K[0, 0, 1] = 0.5
    with pytest.raises(CaptureError, match=r"camera 'cam': K is .*expected \[\[fx, 0, cx\]"):
        Cameras(cams.names, cams.width, cams.height, K, cams.distortion, cams.R, cams.t, source="test")


def test_scaled_cameras_see_scaled_points_at_the_same_pixels():
    cams = one_camera(dist=(0.1, 0, 0.01, 0, 0))
    points = torch.tensor([[0.0, 3.0, -2.0], [1.0, -4.0, 5.0]], dtype=torch.float64)  # metres, say
    in_mm = cams.scaled(1000.0)
    assert in_mm.t[0].tolist() == [0.0, 0.0, 400000.0]
    assert torch.allclose(in_mm.project(points * 1000.0).uv, cams.project(points).uv, atol=1e-9)
