"""torchrefl.report.relight_camera: a pinhole camera's rays (distortion undone) go back through the camera's own
projection (capture.cameras.Cameras.project, with distortion) to their sub-pixel points."""

import numpy as np
import torch

from torchrefl.capture.cameras import Cameras
from torchrefl.report.relight_camera import camera_rays


def test_camera_rays_project_back_onto_their_pixel_points():
    R = torch.linalg.matrix_exp(torch.tensor([[0.0, -0.3, 0.1], [0.3, 0.0, -0.2], [-0.1, 0.2, 0.0]]))
    cams = Cameras.from_arrays(
        ["c"],
        [40],
        [30],
        [50.0],
        [55.0],
        [19.0],
        [15.5],
        [[-0.2, 0.05, 0.01, -0.02, 0.0]],
        R,
        [[5.0, -3.0, 200.0]],
        "t",
    )
    origins, dirs, pixel = camera_rays(cams, 0, 2)
    np.testing.assert_allclose(origins, np.broadcast_to(cams.centres()[0].numpy(), origins.shape))
    np.testing.assert_array_equal(pixel, np.repeat(np.arange(30 * 40), 4))  # 2 x 2 rays per pixel, row-major
    uv = cams.project(torch.from_numpy(origins + 100.0 * dirs), 0).uv.numpy().reshape(30, 40, 4, 2)
    v, u = np.mgrid[0:30, 0:40]
    np.testing.assert_allclose(uv[:, :, 0], np.stack([u - 0.25, v - 0.25], -1), atol=1e-6)
    np.testing.assert_allclose(uv[:, :, 3], np.stack([u + 0.25, v + 0.25], -1), atol=1e-6)
