"""Cameras, lights and pairings of the synthetic mesh_views scenes, in the OpenCV convention."""

import numpy as np
import pytest

from torchrefl.errors import ConfigError, GeometryError
from torchrefl.synthetic.views_layout import ViewLight, look_at, pair_images, ring_cameras


def project(cam, X):
    x = cam.R @ X + cam.t
    return np.array([cam.fx * x[0] / x[2] + cam.cx, cam.fy * x[1] / x[2] + cam.cy]), x[2]


def test_look_at_puts_the_target_at_the_image_centre_with_up_at_the_top():
    cam = look_at("c", [100.0, 50.0, 300.0], [0.0, 10.0, 0.0], 320, 240, 500.0)
    np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(cam.R) > 0
    np.testing.assert_allclose(cam.centre, [100.0, 50.0, 300.0], atol=1e-9)
    uv, z = project(cam, np.array([0.0, 10.0, 0.0]))
    np.testing.assert_allclose(uv, [159.5, 119.5], atol=1e-9)  # top-left pixel centre at (0, 0)
    assert z > 0
    above, _ = project(cam, np.array([0.0, 30.0, 0.0]))
    assert above[1] < 119.5 - 10  # world up is image up (v down)
    right = np.cross(np.array([0.0, 10.0, 0.0]) - cam.centre, [0.0, 1.0, 0.0])  # the camera's right in the world
    side, _ = project(cam, np.array([0.0, 10.0, 0.0]) + 20 * right / np.linalg.norm(right))
    assert side[0] > 159.5 + 10
    with pytest.raises(GeometryError, match="up direction"):
        look_at("c", [0.0, 300.0, 0.0], [0.0, 0.0, 0.0], 32, 32, 50.0)


def test_rays_go_through_their_pixels():
    cam = look_at("c", [0.0, 0.0, 200.0], [0.0, 0.0, 0.0], 8, 6, 40.0)
    o, d, pixel = cam.rays(2)
    assert len(d) == 8 * 6 * 4 and (pixel == np.repeat(np.arange(48), 4)).all()
    X = o + 150.0 * d
    uv = np.array([project(cam, x)[0] for x in X])
    centre = np.stack([pixel % 8, pixel // 8], -1)
    np.testing.assert_allclose(np.abs(uv - centre), 0.25, atol=1e-9)  # the 2 x 2 strata centres
    np.testing.assert_allclose(uv.reshape(48, 4, 2).mean(1), centre[::4], atol=1e-9)


def test_each_camera_gets_its_nearest_lights_and_exposures_cycle():
    target = np.zeros(3)
    cams = ring_cameras(target, 300.0, [0.0], 4, 16, 16, 20.0)  # azimuths 0, 90, 180, 270
    positions = [[0.0, 0.0, 350.0], [350.0, 0.0, 0.0], [0.0, 0.0, -350.0]]
    lights = [ViewLight(f"L{i}", np.array(p), np.ones(3)) for i, p in enumerate(positions)]
    images = pair_images(cams, lights, 2, [1.0, 0.5, 0.25], target)
    assert [(im.camera, im.light) for im in images[:2]] == [("cam00", "L0"), ("cam00", "L1")]
    assert [im.light for im in images[2:4]] == ["L1", "L0"]  # cam01 at +x: L1 first, then the lower index
    assert [im.exposure for im in images] == [1.0, 0.5, 0.25, 1.0, 0.5, 0.25, 1.0, 0.5]
    with pytest.raises(ConfigError, match="lights_per_view is 4"):
        pair_images(cams, lights, 4, [1.0], target)
