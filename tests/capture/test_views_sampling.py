"""What a camera sees of the texels (torchrefl.capture.views_sampling): a texel too narrow in the image to have a
value of its own is left out, by its projected size worked out by hand."""

import numpy as np

from torchrefl.capture.cameras import Cameras
from torchrefl.capture.views_sampling import NARROW_PX, SMALL, camera_view, narrow_warning
from torchrefl.core.rays import RayTracer
from torchrefl.core.texel_grid import TexelGrid

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


def sheared_grid(n: int = 5, width_px: float = 2.0, edge_px: float = 4.0):
    """n x n texels on the plate whose steps are edge_px long in the image and meet at an angle that leaves the
    parallelogram width_px wide across its edges: texel (r, c) at c a + r b (a the column step, b the row step)."""
    s = edge_px * D / F
    sine = width_px / edge_px
    a, b = np.array([s, 0.0, 0.0]), np.array([s * np.sqrt(1 - sine**2), s * sine, 0.0])
    r, c = np.divmod(np.arange(n * n), n)
    points = (c[:, None] - n // 2) * a + (r[:, None] - n // 2) * b
    steps = np.tile(np.stack([a, b], 1), (n * n, 1, 1))
    return (
        points,
        np.tile([0.0, 0.0, 1.0], (n * n, 1)),
        np.full(n * n, s * s * sine),
        steps,
        TexelGrid(np.arange(n * n), (n, n)),
    )


def test_a_sliver_on_a_continuing_face_is_kept_and_one_whose_support_leaves_the_face_is_not():
    # 2 px wide slivers: the value's support (SUPPORT_PX = 1.5 px from the centre) reaches one texel step each way;
    # where those texels exist on the same face the footprint spread describes the blend, elsewhere it mixes
    # another surface (here: the grid's border, and a neighbour whose normal is tilted by 40 degrees)
    cams, plate = plate_below_camera()
    points, normals, areas, steps, grid = sheared_grid()
    view = lambda nb, n=normals: camera_view(  # noqa: E731
        cams, 0, points, n, areas, steps, plate, offset=0.01, min_cos_view=0.1, neighbours=nb
    )
    inner = [r * 5 + c for r in range(1, 4) for c in range(1, 4)]
    border = [t for t in range(25) if t not in inner]
    kept = view(grid)
    assert kept.seen[inner].all() and not kept.seen[border].any()
    assert kept.reasons[SMALL][border].all()
    assert not view(None).seen.any()  # no neighbour structure: every sliver is left out
    tilted = normals.copy()
    tilted[2 * 5 + 3] = [np.sin(np.radians(40)), 0.0, np.cos(np.radians(40))]  # texel (2, 3)
    beside = view(grid, tilted)
    assert not beside.seen[2 * 5 + 2] and beside.seen[1 * 5 + 1]  # (2, 2) borders it, (1, 1) does not


def test_an_atlas_finer_than_the_images_resolve_is_named():
    """Texels left out as narrower than NARROW_PX in every image that shows them are counted against the texels some
    image faces (not those facing away from every camera); above half of them a warning names capture.texture_size
    instead of leaving a mostly empty fit unexplained."""
    seen, narrow = np.zeros((2, 10), dtype=bool), np.zeros((2, 10), dtype=bool)
    seen[:, :3] = True  # 3 texels seen, 4 narrow in both images, 3 left out for other reasons (facing away)
    narrow[:, 3:7] = True
    (named,) = narrow_warning(seen, narrow)
    assert named.startswith("4 of the 7 texels the images face (57%)") and "capture.texture_size" in named
    seen[0, 3] = True  # one of them seen in one image: 3 of 7 left, no warning
    assert narrow_warning(seen, narrow) == []
