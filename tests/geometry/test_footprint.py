"""Mixed footprints from the range data alone: rims, depth steps and creases inside a texel's footprint are
flagged; planes at any tilt, resolved curvature and range noise are not."""

import numpy as np
import pytest
import torch

from torchrefl.errors import GeometryError
from torchrefl.geometry.footprint import mixed_footprints
from torchrefl.geometry.range_image import estimate_range_noise


def height_field(z, dz_dc, dz_dr):
    """Points (c, r, z) on a unit grid and the unit normals of the height field z(c, r) with slopes dz_dc, dz_dr."""
    H, W = z.shape
    r, c = np.meshgrid(np.arange(H, dtype=float), np.arange(W, dtype=float), indexing="ij")
    points = np.stack([c, r, z], -1)
    n = np.stack([-dz_dc, -dz_dr, np.ones_like(z)], -1)
    return points, n / np.linalg.norm(n, axis=-1, keepdims=True)


def flagged(z, dz_dc, dz_dr, measured=None, noise_mm=0.0):
    points, normals = height_field(z, dz_dc, dz_dr)
    valid = np.isfinite(z)
    return mixed_footprints(points if measured is None else measured, points, normals, valid, noise_mm)


@pytest.mark.parametrize("tilt_deg", [0.0, 30.0, 60.0, 75.0])
@pytest.mark.parametrize("azimuth_deg", [0.0, 45.0, 100.0])
def test_a_plane_at_any_tilt_is_not_flagged(tilt_deg, azimuth_deg):
    H, W = 12, 14
    r, c = np.meshgrid(np.arange(H, dtype=float), np.arange(W, dtype=float), indexing="ij")
    g = np.tan(np.radians(tilt_deg))
    gc, gr = g * np.cos(np.radians(azimuth_deg)), g * np.sin(np.radians(azimuth_deg))
    z = gc * c + gr * r
    assert not flagged(z, np.full_like(z, gc), np.full_like(z, gr)).any()


@pytest.mark.parametrize("radius", [2.0, 6.0, 20.0])
def test_a_smooth_sphere_is_not_flagged(radius):
    """A sphere cap, even one only a few texels across: each texel's plane and its neighbour's rise alike (no
    crease between them), and no step."""
    n = int(2 * radius) + 5
    r, c = np.meshgrid(np.arange(n, dtype=float) - n // 2, np.arange(n, dtype=float) - n // 2, indexing="ij")
    inside = r * r + c * c < (0.8 * radius) ** 2
    z = np.where(inside, np.sqrt(np.clip(radius**2 - r * r - c * c, 0, None)), np.nan)
    assert not flagged(z, -c / z, -r / z).any()


@pytest.mark.parametrize("step", [1.0, 3.0, 10.0])
def test_a_depth_step_flags_the_texels_on_both_sides_only(step):
    """A plate lying on a lower plate, its rim at column 6: the rim's texel and the one below it mix the two."""
    z = np.zeros((10, 14))
    z[:, :7] = step
    f = flagged(z, np.zeros_like(z), np.zeros_like(z))
    assert f[:, 6].all() and f[:, 7].all()
    assert not f[:, :6].any() and not f[:, 8:].any()


def test_a_small_step_is_not_flagged():
    """A step of 0.3 texel spacings rises 17 degrees, under MIXED_ANGLE_DEG."""
    z = np.zeros((10, 14))
    z[:, :7] = 0.3
    assert not flagged(z, np.zeros_like(z), np.zeros_like(z)).any()


@pytest.mark.parametrize("offset,mixed", [(0.0, True), (0.2, True), (0.3, True), (0.4, False), (0.5, False)])
@pytest.mark.parametrize("tilt", [0.0, 0.3])
def test_a_fold_flags_the_texel_whose_footprint_it_crosses(offset, mixed, tilt):
    """A 90-degree fold z = |c - c0| (each side at 45 degrees, the whole tilted along the rows) with the fold
    line at c0 = 6 + offset: texel 6 is mixed when more than a sixth of its footprint (which reaches half-way to
    its neighbours) lies across the fold, offset < 1/3; on the fold line it carries both sides' mixed normal.
    A fold between two texels leaves both clean, and no other texel is ever flagged."""
    c0 = 6.0 + offset
    H, W = 8, 14
    r, c = np.meshgrid(np.arange(H, dtype=float), np.arange(W, dtype=float), indexing="ij")
    z = np.abs(c - c0) + tilt * r
    f = flagged(z, np.sign(c - c0), np.full_like(z, tilt))
    assert f[:, 6].all() if mixed else not f[:, 6].any()
    assert not f[:, :6].any() and not f[:, 7:].any()


def test_a_plate_rim_is_flagged():
    """A 3 mm plate seen from above: its inside face, a vertical end face and the background plane below."""
    z = np.full((10, 16), -20.0)
    z[:, :8] = 0.0
    z[:, 8] = -1.5  # the end face, half-way down
    dz_dc = np.zeros_like(z)
    dz_dc[:, 8] = -3.0  # the end face's normal is near-horizontal
    f = flagged(z, dz_dc, np.zeros_like(z))
    assert f[:, 7].all() and f[:, 9].all()  # the inside face's last texel, the background's first
    assert not f[:, :7].any() and not f[:, 10:].any()


def test_range_noise_is_forgiven_when_estimated():
    """A plane whose measured points carry range noise: with the noise estimated from the data nothing is
    flagged; counted as geometry (noise 0), steep noise would be."""
    rng = np.random.default_rng(0)
    z = np.zeros((40, 40))
    points, normals = height_field(z, np.zeros_like(z), np.zeros_like(z))
    noisy = points.copy()
    noisy[..., 2] += rng.normal(0.0, 0.15, z.shape)
    # the estimate preprocessing makes (RangeGeometry.noise_mm) of the same noise on a range image
    sigma = estimate_range_noise(torch.from_numpy(noisy[..., 2]), torch.ones(z.shape, dtype=torch.bool))
    assert 0.1 < sigma < 0.2
    valid = np.ones_like(z, bool)
    assert mixed_footprints(noisy, points, normals, valid, noise_mm=0.0).any()
    assert not mixed_footprints(noisy, points, normals, valid, noise_mm=sigma).any()


def test_columns_wrap_around_for_a_full_turn():
    """With wrap, the last column's neighbour is the first: a step between them is seen from both sides."""
    z = np.zeros((6, 10))
    z[:, 0] = 50.0
    points, normals = height_field(z, np.zeros_like(z), np.zeros_like(z))
    points[..., 0] = np.arange(10) % 10  # the grid's x is not periodic here: only the wrap pairs the points
    valid = np.ones_like(z, bool)
    plain = mixed_footprints(points, points, normals, valid)
    assert plain[:, 0].all() and plain[:, 1].all() and not plain[:, -1].any()
    assert mixed_footprints(points, points, normals, valid, wrap=True)[:, -1].all()


def test_invalid_and_missing_neighbours():
    z = np.zeros((6, 8))
    z[2:4, 3:5] = np.nan
    points, normals = height_field(z, np.zeros_like(z), np.zeros_like(z))
    valid = np.isfinite(z)
    assert not mixed_footprints(points, points, normals, valid).any()


def test_bad_arguments_are_named():
    p = np.zeros((4, 5, 3))
    valid = np.ones((4, 5), bool)
    with pytest.raises(GeometryError, match="'points'"):
        mixed_footprints(p, np.zeros((4, 4, 3)), p, valid)
    with pytest.raises(GeometryError, match="noise_mm"):
        mixed_footprints(p, p, p, valid, noise_mm=-1.0)
    with pytest.raises(GeometryError, match="'valid'"):
        mixed_footprints(p, p, p, np.ones((3, 3), bool))


def fitted(r: np.ndarray):
    """preprocess_range_image of a range image r (H, W) mm (NaN: no scan) on a 0.7 degree x 0.56 mm grid."""
    from torchrefl.geometry.range_image import preprocess_range_image

    valid = np.isfinite(r)
    return preprocess_range_image(
        torch.from_numpy(np.where(valid, r, 0.0)),
        torch.from_numpy(valid),
        s0=0.0,
        ds=np.radians(0.7),
        t0=0.0,
        dt=0.56,
        median_size=None,
        window=5,
        noise_tolerance=2.0,
    )


def unfit(r: np.ndarray) -> np.ndarray:
    from torchrefl.geometry.footprint import unfit_windows

    geo = fitted(r)
    return unfit_windows(geo.fit_rms_mm.numpy(), geo.valid.numpy(), geo.spacing_mm, geo.noise_mm)


def plate_with_end_face(rows=40, cols=40, face_rows=3) -> np.ndarray:
    """A plate leaning back (range grows 0.6 mm per mm of height) up to a crease on row rows - 5 - face_rows, then
    its end face (range falls 3 mm per mm) on the face_rows - 1 rows up to the scan's edge: a strip narrower than
    the fitting window."""
    dt = 0.56
    r = np.full((rows, cols), np.nan)
    plate = rows - 5 - face_rows
    for i in range(rows - 5):
        r[i] = 60.0 + 0.6 * dt * min(i, plate) - 3.0 * dt * max(i - plate, 0)
    return r


def test_a_strip_narrower_than_the_fitting_window_is_untrusted_and_the_plate_is_not():
    flags = unfit(plate_with_end_face())
    assert flags[33:35, 5:-5].all()  # the end face; the crease row 32 is the footprint test's
    assert not flags[:26].any()  # every window of these rows lies on the plate


def test_smooth_surfaces_are_not_untrusted_with_or_without_range_noise():
    rows, cols = np.mgrid[0:40, 0:40].astype(np.float64)
    smooth = 60.0 + 3.0 * np.cos(rows * 0.56 / 10.0) * np.cos(cols * np.radians(0.7) * 5.0)
    assert not unfit(smooth).any()
    noisy = smooth + np.random.default_rng(0).normal(0.0, 0.05, smooth.shape)
    assert not unfit(noisy).any()


def test_unfit_windows_names_a_bad_spacing():
    from torchrefl.geometry.footprint import unfit_windows

    with pytest.raises(GeometryError, match="spacing_mm"):
        unfit_windows(np.zeros((3, 3)), np.ones((3, 3), bool), 0.0)
