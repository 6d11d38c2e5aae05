"""Range-image preprocessing (section 2.3): median filter, Yokoya-Levine quadratic fit, eq. 2.1 points and
outward normals, all checked against analytic surfaces (spheres, an off-axis ellipsoid, cylinders)."""

import math

import numpy as np
import pytest
import torch

from torchrefl.errors import GeometryError
from torchrefl.geometry.cylindrical import cylindrical_normals, cylindrical_points
from torchrefl.geometry.range_image import (
    NOISE_FREE_NORMAL_DEG,
    auto_median_size,
    estimate_range_noise,
    fit_quadratic_yokoya_levine,
    preprocess_range_image,
)
from torchrefl.geometry.range_median import median_filter_range

DS = math.radians(0.7)  # the seed scanner (Table 2.1)
DT = 0.56


def axes(H, W, s0, t0, ds=DS, dt=DT, dtype=torch.float64):
    s = s0 + ds * torch.arange(W, dtype=dtype)
    t = t0 + dt * torch.arange(H, dtype=dtype)
    return s, t


def radial(s):
    """(W, 3) unit radial direction of each column, eq. 2.1 with r = 1, t = 0."""
    return torch.stack([-torch.sin(s), torch.zeros_like(s), -torch.cos(s)], -1)


def sphere(s, t, R, tc=0.0):
    """Sphere of radius R centred on the axis at height tc: range (H, W), valid, outward normals (H, W, 3)."""
    H, W = t.numel(), s.numel()
    dz = t - tc
    valid = (dz.abs() < R)[:, None].expand(H, W).clone()
    r = torch.sqrt((R**2 - dz**2).clamp_min(0))[:, None].expand(H, W).clone()
    p = r[..., None] * radial(s)[None]
    p[..., 1] = -dz[:, None]
    return r, valid, p / R


def ellipsoid(s, t, centre=(12.0, 4.0, -9.0), semi=(70.0, 55.0, 50.0)):
    """Off-axis ellipsoid seen by the scanner: the outermost hit of the radial line of each pixel.
    Returns range (H, W), valid (H, W), analytic outward normals (H, W, 3), analytic points (H, W, 3)."""
    c = torch.tensor(centre, dtype=s.dtype)
    a = torch.tensor(semi, dtype=s.dtype)
    u = radial(s)[None].expand(t.numel(), -1, -1)
    o = torch.zeros_like(u)
    o[..., 1] = -t[:, None]
    oc, d = (o - c) / a, u / a
    A = (d * d).sum(-1)
    B = 2 * (oc * d).sum(-1)
    C = (oc * oc).sum(-1) - 1
    disc = B * B - 4 * A * C
    lam = (-B + torch.sqrt(disc.clamp_min(0))) / (2 * A)
    valid = (disc > 0) & (lam > 0)
    r = torch.where(valid, lam, torch.zeros_like(lam))
    p = o + r[..., None] * u
    n = (p - c) / a**2
    return r, valid, n / n.norm(dim=-1, keepdim=True), p


def angle_deg(n1, n2):
    return torch.rad2deg(torch.acos((n1 * n2).sum(-1).clamp(-1, 1)))


def erode(valid, k):
    """Pixels whose (2k+1) x (2k+1) neighbourhood is valid (image border counts as invalid)."""
    v = valid.to(torch.float64)[None, None]
    return (-torch.nn.functional.max_pool2d(-v, 2 * k + 1, stride=1, padding=k, ceil_mode=False)[0, 0] > 0.5) & (
        torch.nn.functional.pad(torch.ones(valid.shape[0] - 2 * k, valid.shape[1] - 2 * k), (k, k, k, k)) > 0
    )


def run(r, valid, s, t, **kw):
    return preprocess_range_image(
        r, valid, s0=float(s[0]), ds=float(s[1] - s[0]), t0=float(t[0]), dt=float(t[1] - t[0]), **kw
    )


# ------------------------------------------------------------------ eq. 2.1 / 2.3 / 2.4


def test_cylinder_normals_are_exactly_radial_and_outward():
    s, t = axes(30, 40, s0=-1.0, t0=-5.0)
    r = torch.full((30, 40), 60.0, dtype=torch.float64)
    valid = torch.rand(30, 40, generator=torch.Generator().manual_seed(1)) > 0.1
    g = run(r, valid, s, t)
    expected = radial(s)[None].expand(30, 40, 3)
    assert g.valid.sum() > 0.8 * valid.sum()
    torch.testing.assert_close(g.normals[g.valid], expected[g.valid], atol=1e-12, rtol=0)
    assert ((g.normals * g.points).sum(-1)[g.valid] > 0).all()  # away from the axis
    assert torch.isnan(g.normals[~g.valid]).all()


# ------------------------------------------------------------------ analytic surfaces


def test_sphere_normals_and_points_match_analytic_including_image_border():
    s, t = axes(140, 120, s0=-0.7, t0=-62.0)
    r, valid, n_true = sphere(s, t, 80.0)
    g = run(r, valid, s, t)
    assert g.valid.all()
    err = angle_deg(g.normals, n_true)
    # the 5 x 5 median flattens the ridge r(t) has at the equator (t = 0: r(0) -> r(+-dt)); elsewhere the error
    # is the quadratic fit's own, border rows included (evaluated at the pixel, not at the window centre)
    ridge = (t.abs() < 3 * DT)[:, None].expand_as(err)
    assert err[~ridge].max() < 0.05, float(err[~ridge].max())
    assert err.max() < 0.25, float(err.max())
    p_true = 80.0 * n_true
    assert (g.points - p_true).norm(dim=-1).max() < 5e-3
    no_median = run(r, valid, s, t, median_size=1)
    assert angle_deg(no_median.normals, n_true).max() < 0.05


def test_off_axis_ellipsoid_normals_match_analytic_in_interior():
    s, t = axes(200, 180, s0=-1.2, t0=-52.0)
    r, valid, n_true, p_true = ellipsoid(s, t)
    assert (~valid).any() and valid.sum() > 0.5 * valid.numel()  # silhouettes inside the image
    # interior: away from silhouettes (4 px), not grazing, not near the poles where r ~ sqrt(t - t_pole) is far
    # from a quadratic in (s, t)
    interior = erode(valid, 4) & ((n_true * radial(s)[None]).sum(-1) > 0.5) & (n_true[..., 1].abs() < 0.8)
    assert interior.sum() > 0.4 * valid.numel()
    fit_only = run(r, valid, s, t, median_size=1)
    err = angle_deg(fit_only.normals, n_true)[interior]
    assert err.max() < 0.2, float(err.max())
    assert (fit_only.points - p_true).norm(dim=-1)[interior].max() < 5e-3
    # the seed's chain: the 5 x 5 median adds a bias along the ridges of r (where the window's rank order flips)
    g = run(r, valid, s, t)
    err = angle_deg(g.normals, n_true)[interior]
    assert err.median() < 0.05 and err.quantile(0.95) < 0.2, (float(err.median()), float(err.quantile(0.95)))
    assert err.max() < 1.5, float(err.max())
    # outward everywhere it is valid, silhouettes included: away from the ellipsoid centre
    c = torch.tensor([12.0, 4.0, -9.0], dtype=torch.float64)
    assert ((g.normals - 0) * (g.points - c)).sum(-1)[g.valid].min() > 0


def test_full_turn_wraps_across_the_seam():
    W = 512
    s, t = axes(30, W, s0=0.0, t0=-8.0, ds=2 * math.pi / W)
    r, valid, n_true, _ = ellipsoid(s, t)
    assert valid.all()
    seam = torch.zeros_like(valid)
    seam[:, [W - 2, W - 1, 0, 1, 2]] = True  # a 5-column strip that is only 5 wide across the seam
    f = fit_quadratic_yokoya_levine(r, seam, 2 * math.pi / W, DT, wrap=True)
    n = cylindrical_normals(f.r_hat, f.r_s, f.r_t, s, t)
    assert f.valid[seam].all() and not f.fallback.any()
    assert angle_deg(n, n_true)[seam].max() < 0.2
    f_open = fit_quadratic_yokoya_levine(r, seam, 2 * math.pi / W, DT, wrap=False)
    assert not f_open.valid[:, W - 2 :].any()  # without wrap: a 2-column strip, not fittable
    assert f_open.fallback[:, :3].all()
    # a spike on the seam column is removed with the neighbours across the seam
    spiked = r.clone()
    spiked[15, 0] += 20.0
    m = median_filter_range(spiked, valid, wrap=True)
    assert abs(float(m[15, 0] - r[15, 0])) < 0.05


@pytest.mark.parametrize("surface", ["sphere", "ellipsoid"])
def test_gaussian_range_noise_keeps_normals_within_about_a_degree(surface):
    s, t = axes(120, 140, s0=-0.8, t0=-40.0)
    if surface == "sphere":
        r, valid, n_true = sphere(s, t, 80.0)
    else:
        r, valid, n_true, _ = ellipsoid(s, t)
    noisy = r + 0.05 * torch.randn(r.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    interior = erode(valid, 4) & ((n_true * radial(s)[None]).sum(-1) > 0.3)
    strict = angle_deg(run(noisy, valid, s, t).normals, n_true)[interior]  # the seed's minimum-residual rule
    assert strict.median() < 1.5, float(strict.median())
    assert strict.quantile(0.9) < 4.0, float(strict.quantile(0.9))
    tolerant = angle_deg(run(noisy, valid, s, t, noise_tolerance=2.0).normals, n_true)[interior]
    assert tolerant.median() < 0.8, float(tolerant.median())
    assert tolerant.median() < 0.7 * strict.median()


def test_eight_bit_range_quantisation_full_seed_resolution():
    H, W = 450, 512  # the seed scanner's image
    s, t = axes(H, W, s0=-W / 2 * DS, t0=-H / 2 * DT)
    r, valid, n_true, _ = ellipsoid(s, t, semi=(70.0, 150.0, 50.0))
    lo, hi = float(r[valid].min()), float(r[valid].max())
    step = (hi - lo) / 255
    q = lo + torch.round((r - lo) / step) * step
    assert step > 0.1  # a coarse quantiser, not a no-op
    interior = erode(valid, 4) & ((n_true * radial(s)[None]).sum(-1) > 0.3)
    strict = angle_deg(run(q, valid, s, t).normals, n_true)[interior]
    assert strict.median() < 4.0, float(strict.median())  # windows on one 8-bit level win with residual 0
    tolerant = angle_deg(run(q, valid, s, t, noise_tolerance=2.0).normals, n_true)[interior]
    assert tolerant.median() < 1.5 and tolerant.quantile(0.9) < 3.5, (
        float(tolerant.median()),
        float(tolerant.quantile(0.9)),
    )


# ------------------------------------------------------------------ discontinuities


def two_spheres_with_step(axis):
    """Sphere radius 80 on one side of a step, radius 70 on the other; both centred at the origin, so the analytic
    normal is p / |p| everywhere. Step between rows 39/40 (axis 't') or columns 39/40 (axis 's')."""
    s, t = axes(80, 80, s0=-0.5, t0=12.0)
    t_grid = t[:, None].expand(80, 80)
    R = torch.full((80, 80), 80.0, dtype=torch.float64)
    if axis == "t":
        R[40:] = 70.0
    else:
        R[:, 40:] = 70.0
    r = torch.sqrt(R**2 - t_grid**2)
    p = cylindrical_points(r, s, t)
    return s, t, r, p / p.norm(dim=-1, keepdim=True)


@pytest.mark.parametrize("tolerance", [0.0, 2.0])
@pytest.mark.parametrize("axis", ["t", "s"])
def test_yokoya_levine_stays_accurate_next_to_a_depth_step(axis, tolerance):
    s, t, r, n_true = two_spheres_with_step(axis)
    valid = torch.ones_like(r, dtype=torch.bool)
    near = torch.zeros_like(valid)
    if axis == "t":
        near[38:42, 5:-5] = True
    else:
        near[5:-5, 38:42] = True
    errs = {}
    for adaptive in (True, False):
        f = fit_quadratic_yokoya_levine(r, valid, DS, DT, adaptive=adaptive, noise_tolerance=tolerance)
        n = cylindrical_normals(f.r_hat, f.r_s, f.r_t, s, t)
        errs[adaptive] = angle_deg(n, n_true)[near]
    assert errs[True].max() < 2.0, float(errs[True].max())
    assert errs[False].median() > 20.0, float(errs[False].median())  # the plain centred fit is far off
    assert errs[True].max() < 0.05 * errs[False].median()


# ------------------------------------------------------------------ median filter


def test_median_removes_isolated_spikes_and_keeps_a_smooth_surface():
    s, t = axes(80, 90, s0=-0.5, t0=-20.0)
    r, valid, _, _ = ellipsoid(s, t)
    assert valid.all()
    spiked = r.clone()
    rows, cols = torch.meshgrid(torch.arange(5, 80, 9), torch.arange(4, 90, 11), indexing="ij")
    spiked[rows, cols] += torch.where((rows + cols) % 2 == 0, 15.0, -15.0).to(torch.float64)
    m = median_filter_range(spiked, valid)
    assert (m[rows, cols] - r[rows, cols]).abs().max() < 0.25  # the 15 mm spikes are gone
    inner = erode(valid, 2)
    assert (m - r).abs()[inner].max() < 0.25  # no spike leaks into its neighbours
    clean = median_filter_range(r, valid)
    assert (clean - r).abs()[inner].max() < 0.05  # a smooth surface is kept
    # on noise: the median reduces the error, never adds to it
    noisy = r + 0.05 * torch.randn(r.shape, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    mn = median_filter_range(noisy, valid)
    assert (mn - r)[inner].std() < 0.6 * 0.05


def test_symmetric_median_is_exact_on_a_ramp_with_holes_and_border():
    s, t = axes(40, 50, s0=0.0, t0=0.0)
    r = 50 + 3.0 * s[None, :] * 10 + 0.7 * t[:, None]
    valid = torch.rand(40, 50, generator=torch.Generator().manual_seed(5)) > 0.3
    m = median_filter_range(r, valid)
    torch.testing.assert_close(m[valid], r[valid], atol=1e-12, rtol=0)
    plain = median_filter_range(r, valid, symmetric=False)
    assert (plain - r)[valid].abs().max() > 0.3  # what the symmetric window avoids


def test_invalid_pixels_never_influence_valid_ones():
    s, t = axes(50, 60, s0=-0.4, t0=-15.0)
    r, valid, _, _ = ellipsoid(s, t)
    valid = valid & (torch.rand(50, 60, generator=torch.Generator().manual_seed(6)) > 0.15)
    base = r.clone()
    base[~valid] = 0.0
    g0 = run(base, valid, s, t)
    m0 = median_filter_range(base, valid)
    for junk in (1e9, -1e9, float("nan"), float("inf")):
        other = base.clone()
        other[~valid] = junk
        g = run(other, valid, s, t)
        assert torch.equal(g.valid, g0.valid)
        assert torch.equal(g.normals[g.valid], g0.normals[g0.valid])
        assert torch.equal(g.points[g.valid], g0.points[g0.valid])
        m = median_filter_range(other, valid)
        assert torch.equal(m[valid], m0[valid])
        assert torch.equal(m[~valid].isnan(), other[~valid].isnan())  # invalid pixels untouched


# ------------------------------------------------------------------ fallback for thin features


def test_thin_strip_uses_weighted_fallback_and_too_thin_is_invalid():
    s, t = axes(40, 30, s0=-0.3, t0=-30.0)
    r, _, n_true = sphere(s, t, 80.0)
    valid = torch.zeros(40, 30, dtype=torch.bool)
    valid[:, 10:13] = True  # 3 columns: no full 5 x 5 window, but a well-posed partial one
    valid[:, 20:22] = True  # 2 columns: the s-curvature is not determined
    valid[20, 26] = True  # a lone pixel
    f = fit_quadratic_yokoya_levine(r, valid, DS, DT)
    assert f.fallback[:, 10:13].all() and f.valid[:, 10:13].all()
    n = cylindrical_normals(f.r_hat, f.r_s, f.r_t, s, t)
    assert angle_deg(n, n_true)[:, 10:13].max() < 0.5
    assert not f.valid[:, 20:22].any() and not f.valid[20, 26]
    assert torch.isnan(f.r_hat[:, 20:22]).all()


# ------------------------------------------------------------------ precision


def test_float32_agrees_with_float64():
    s, t = axes(90, 100, s0=-0.6, t0=-30.0)
    r, valid, _, _ = ellipsoid(s, t)
    r = r + 0.05 * torch.randn(r.shape, generator=torch.Generator().manual_seed(7), dtype=torch.float64)
    g64 = run(r, valid, s, t)
    g32 = run(r.float(), valid, s.float(), t.float())
    assert g32.normals.dtype == torch.float32
    both = g64.valid & g32.valid
    assert both.sum() == g64.valid.sum()
    diff = (g32.normals.double() - g64.normals)[both].abs().amax(-1)
    assert diff.median() < 1e-5 and diff.quantile(0.99) < 1e-4, (float(diff.median()), float(diff.quantile(0.99)))


# ------------------------------------------------------------------ bad input


def _good():
    r = torch.full((12, 12), 50.0, dtype=torch.float64)
    return r, torch.ones(12, 12, dtype=torch.bool)


def _call_pre(r=None, valid=None, **kw):
    gr, gv = _good()
    args = dict(s0=0.0, ds=DS, t0=0.0, dt=DT)
    args.update(kw)
    return preprocess_range_image(gr if r is None else r, gv if valid is None else valid, **args)


def _nan_inside():
    r, _ = _good()
    r[3, 4] = float("nan")
    return r


BAD = [
    ("r", lambda: _call_pre(r=np.full((12, 12), 50.0))),
    ("r", lambda: _call_pre(r=torch.full((12, 12), 50, dtype=torch.int32))),
    ("r", lambda: _call_pre(r=torch.full((2, 12, 12), 50.0))),
    ("valid", lambda: _call_pre(valid=torch.ones(12, 12))),
    ("valid", lambda: _call_pre(valid=torch.ones(12, 11, dtype=torch.bool))),
    ("valid", lambda: _call_pre(valid=torch.zeros(12, 12, dtype=torch.bool))),
    ("r", lambda: _call_pre(r=_nan_inside())),
    ("window", lambda: _call_pre(window=4)),
    ("window", lambda: _call_pre(window=1)),
    ("window", lambda: _call_pre(window=5.0)),
    ("window", lambda: _call_pre(window=True)),
    ("median_size", lambda: _call_pre(median_size=0)),
    ("median_size", lambda: _call_pre(median_size=6)),
    ("ds", lambda: _call_pre(ds=0.0)),
    ("dt", lambda: _call_pre(dt=-1.0)),
    ("noise_tolerance", lambda: _call_pre(noise_tolerance=-1.0)),
    ("s0", lambda: _call_pre(s0=float("nan"))),
    ("wrap", lambda: _call_pre(wrap=True)),
    (
        "r",
        lambda: fit_quadratic_yokoya_levine(
            torch.ones(4, 12, dtype=torch.float64), torch.ones(4, 12, dtype=torch.bool), DS, DT
        ),
    ),
    ("size", lambda: median_filter_range(*_good(), size=-3)),
]


@pytest.mark.parametrize("name,call", BAD, ids=[f"{i}-{b[0]}" for i, b in enumerate(BAD)])
def test_bad_input_raises_geometry_error_naming_the_argument(name, call):
    with pytest.raises(GeometryError, match=f"'{name}'"):
        call()


# ------------------------------------------------------------------ the automatic median (geometry.median_size: null)


def crease(s, t, R0=60.0, slopes=(0.3, -1.7)):
    """A crease along the scan direction: r = R0 + slope t with one slope above and one below t = 0 (two cones
    meeting at a valley, the inside of a fold of about 100 deg, its sides unequally inclined like Object E's).
    Returns range (H, W), valid, analytic outward normals away from the crease line."""
    H, W = t.numel(), s.numel()
    slope = torch.where(t >= 0, slopes[0], slopes[1]).to(t.dtype)
    r = (R0 + slope * t)[:, None].expand(H, W).clone()
    r_t = slope[:, None].expand(H, W)
    n = cylindrical_normals(r, torch.zeros_like(r), r_t, s, t)
    return r, torch.ones(H, W, dtype=torch.bool), n


def test_range_noise_estimate_matches_the_added_noise_and_ignores_edges_and_creases():
    s, t = axes(200, 180, s0=-1.2, t0=-52.0)
    r, valid, _, _ = ellipsoid(s, t)
    assert estimate_range_noise(r, valid) < 1e-4  # silhouettes and the quadratic's own misfit are not noise
    gen = torch.Generator().manual_seed(0)
    for sd in (0.02, 0.1):
        noisy = r + sd * torch.randn(r.shape, generator=gen, dtype=r.dtype)
        assert estimate_range_noise(noisy, valid) == pytest.approx(sd, rel=0.15)
    s, t = axes(120, 100, s0=-0.5, t0=-33.6)
    r, valid, _ = crease(s, t)
    assert estimate_range_noise(r, valid) < 1e-6


def test_auto_median_keeps_a_clean_fold_and_filters_a_noisy_one():
    s, t = axes(120, 100, s0=-0.5, t0=-33.6 - DT / 2)  # no row on the crease line itself
    r, valid, n_true = crease(s, t)
    near = (t.abs() < 3 * DT)[:, None].expand(r.shape).clone()  # the rows next to the crease line
    near[:, :6] = near[:, -6:] = False
    auto = run(r, valid, s, t, median_size=None)
    assert auto.median_size == 1 and auto.noise_mm < 1e-6
    assert angle_deg(auto.normals, n_true)[near].max() < 0.1
    rounded = run(r, valid, s, t, median_size=5)  # the seed's median rounds the fold it does not need to touch
    assert angle_deg(rounded.normals, n_true)[near].max() > 2.0
    gen = torch.Generator().manual_seed(1)
    noisy = run(r + 0.1 * torch.randn(r.shape, generator=gen, dtype=r.dtype), valid, s, t, median_size=None)
    assert noisy.median_size == 5 and noisy.noise_mm == pytest.approx(0.1, rel=0.2)


def test_auto_median_threshold_follows_the_normal_tilt_of_the_noise():
    s, t = axes(60, 60, s0=-0.3, t0=-16.0)
    r, valid, _ = crease(s, t)
    h = DT  # the height step is the smaller step here (arc 60 mm x 0.7 deg = 0.73 mm)
    spread = math.sqrt(25 * 24 / 12)
    at_threshold = math.radians(NOISE_FREE_NORMAL_DEG) * h * spread
    assert auto_median_size(0.9 * at_threshold, r, valid, float(s[1] - s[0]), h, 5) == 1
    assert auto_median_size(1.1 * at_threshold, r, valid, float(s[1] - s[0]), h, 5) == 5
