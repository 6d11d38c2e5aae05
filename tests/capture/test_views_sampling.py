"""What a camera sees of the texels (torchrefl.capture.views_sampling): a texel too narrow in the image to have a
value of its own is left out, by its projected size worked out by hand."""

import numpy as np

from torchrefl.capture.cameras import Cameras
from torchrefl.capture.views_sampling import NARROW_PX, SMALL, camera_view
from torchrefl.core.rays import RayTracer

F, D = 1000.0, 500.0  # focal length (px) and the camera's height above the plate (mm)


def plate_below_camera():
    """A square plate in z = 0 facing +z, a camera D mm above it looking down (R: x right, y down, z forward = -z)."""
    cams = Cameras.from_arrays(
        ["top"], [640], [480], [F], [F], [320.0], [240.0], [(0, 0, 0, 0, 0)],
        [[[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]], [(0.0, 0.0, D)], source="test",
    )  # fmt: skip
    plate = RayTracer(
        np.array([[-60, -60, 0], [60, -60, 0], [60, 60, 0], [-60, 60, 0]], float), np.array([[0, 1, 2], [0, 2, 3]])
    )
    return cams, plate


def test_a_texel_narrower_than_narrow_px_in_the_image_is_left_out():
    cams, plate = plate_below_camera()
    # two texels near the axis whose steps project (f / D per mm) just under and just over NARROW_PX
    px = np.array([NARROW_PX - 0.1, NARROW_PX + 0.1])
    side = px * D / F
    points = np.array([[-10.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    steps = np.zeros((2, 3, 2))
    steps[:, 0, 0] = side
    steps[:, 1, 1] = side
    view = camera_view(
        cams, 0, points, np.tile([0.0, 0.0, 1.0], (2, 1)), side**2, steps, plate, offset=0.01, min_cos_view=0.1
    )
    assert view.reasons[SMALL].tolist() == [True, False]
    assert view.seen.tolist() == [False, True]


def test_a_sheared_texel_is_narrow_by_its_width_not_by_its_edges():
    # the texel's two steps are 4 px long in the image but meet at an angle: the parallelogram's width across its
    # edges is 4 px * sin(angle), the distance its bilinear support has to stay clear of its neighbours
    cams, plate = plate_below_camera()
    edge_px = 4.0
    s = edge_px * D / F
    sines = np.array([(NARROW_PX - 0.5) / edge_px, (NARROW_PX + 0.5) / edge_px])  # widths 2.0 and 3.0 px
    points = np.array([[-10.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    steps = np.zeros((2, 3, 2))
    steps[:, 0, 0] = s
    steps[:, 0, 1] = s * np.sqrt(1 - sines**2)
    steps[:, 1, 1] = s * sines
    areas = s * s * sines
    view = camera_view(
        cams, 0, points, np.tile([0.0, 0.0, 1.0], (2, 1)), areas, steps, plate, offset=0.01, min_cos_view=0.1
    )
    assert view.reasons[SMALL].tolist() == [True, False]
    assert view.seen.tolist() == [False, True]
