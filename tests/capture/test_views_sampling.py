"""What a camera sees of the texels (torchrefl.capture.views_sampling): a texel too narrow in the image to have a
value of its own is left out, by its projected size worked out by hand."""

import numpy as np

from torchrefl.capture.cameras import Cameras
from torchrefl.capture.views_sampling import NARROW_PX, SMALL, camera_view
from torchrefl.core.rays import RayTracer


def test_a_texel_narrower_than_narrow_px_in_the_image_is_left_out():
    # a square plate in z = 0 facing +z, a camera 500 mm above it looking down (R: x right, y down, z forward = -z)
    f, D = 1000.0, 500.0
    cams = Cameras.from_arrays(
        ["top"], [640], [480], [f], [f], [320.0], [240.0], [(0, 0, 0, 0, 0)],
        [[[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]], [(0.0, 0.0, D)], source="test",
    )  # fmt: skip
    plate = RayTracer(
        np.array([[-60, -60, 0], [60, -60, 0], [60, 60, 0], [-60, 60, 0]], float), np.array([[0, 1, 2], [0, 2, 3]])
    )
    # two texels near the axis whose steps project (f / D per mm) just under and just over NARROW_PX
    px = np.array([NARROW_PX - 0.1, NARROW_PX + 0.1])
    side = px * D / f
    points = np.array([[-10.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    steps = np.zeros((2, 3, 2))
    steps[:, 0, 0] = side
    steps[:, 1, 1] = side
    view = camera_view(
        cams, 0, points, np.tile([0.0, 0.0, 1.0], (2, 1)), side**2, steps, plate, offset=0.01, min_cos_view=0.1
    )
    assert view.reasons[SMALL].tolist() == [True, False]
    assert view.seen.tolist() == [False, True]
