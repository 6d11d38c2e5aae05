"""BRDF module: against the dissertation's formulas written out directly, gradchecks, extremes."""

import math

import numpy as np
import pytest
import torch

from torchrefl.core import brdf
from torchrefl.errors import ConfigError

MODELS = ["torrance_sparrow", "ward", "ward_normalised"]


def random_unit(n, rng, hemisphere_of=None):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if hemisphere_of is not None:
        flip = (v * hemisphere_of).sum(1) < 0
        v[flip] *= -1
    return v


def config(n=200, seed=0):
    rng = np.random.default_rng(seed)
    nrm = random_unit(n, rng)
    l = random_unit(n, rng, nrm)
    v = random_unit(n, rng, nrm)
    pd = rng.uniform(0, 1, (n, 3))
    ps = rng.uniform(0, 1, (n, 3))
    sigma = rng.uniform(0.05, 0.5, n)
    return nrm, l, v, pd, ps, sigma


def eq_2_9(nrm, l, v, pd, ps, sigma):
    """i * C^2 / Y of eq. 2.9 with the seed's acos definition of theta_r."""
    cos_d = (nrm * l).sum(1)
    cos_v = (nrm * v).sum(1)
    h = (l + v) / np.linalg.norm(l + v, axis=1, keepdims=True)
    th = np.arccos(np.clip((nrm * h).sum(1), -1, 1))
    return pd * cos_d[:, None] + ps / cos_v[:, None] * np.exp(-(th**2) / (2 * sigma**2))[:, None]


def eq_5_9(nrm, l, v, pd, ps, sigma, normalised):
    cos_l = (nrm * l).sum(1)
    cos_v = (nrm * v).sum(1)
    h = (l + v) / np.linalg.norm(l + v, axis=1, keepdims=True)
    th = np.arccos(np.clip((nrm * h).sum(1), -1, 1))
    spec = np.exp(-(np.tan(th) ** 2) / sigma**2) / (4 * math.pi * sigma**2)
    if normalised:
        spec = spec / np.sqrt(cos_l * cos_v)
    return (pd / math.pi + ps * spec[:, None]) * cos_l[:, None]


def T(x):
    return torch.from_numpy(np.asarray(x, dtype=np.float64))


def test_torrance_sparrow_with_kappa_pi_is_eq_2_9():
    nrm, l, v, pd, ps, sigma = config()
    g = brdf.cosine_weighted_brdf("torrance_sparrow", T(nrm), T(l), T(v), T(pd), T(ps), T(sigma))
    np.testing.assert_allclose(math.pi * g.numpy(), eq_2_9(nrm, l, v, pd, ps, sigma), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("normalised", [False, True])
def test_ward_is_eq_5_9(normalised):
    nrm, l, v, pd, ps, sigma = config(seed=1)
    name = "ward_normalised" if normalised else "ward"
    g = brdf.cosine_weighted_brdf(name, T(nrm), T(l), T(v), T(pd), T(ps), T(sigma))
    np.testing.assert_allclose(g.numpy(), eq_5_9(nrm, l, v, pd, ps, sigma, normalised), rtol=1e-8, atol=1e-12)


def test_grey_ps_broadcasts_over_channels():
    nrm, l, v, pd, ps, sigma = config(seed=2)
    grey = ps[:, :1]
    a = brdf.cosine_weighted_brdf("ward", T(nrm), T(l), T(v), T(pd), T(grey), T(sigma))
    b = brdf.cosine_weighted_brdf("ward", T(nrm), T(l), T(v), T(pd), T(np.repeat(grey, 3, 1)), T(sigma))
    torch.testing.assert_close(a, b)


def test_angle_between_matches_acos_and_is_finite_at_parallel():
    rng = np.random.default_rng(3)
    a, b = random_unit(100, rng), random_unit(100, rng)
    ref = np.arccos(np.clip((a * b).sum(1), -1, 1))
    np.testing.assert_allclose(brdf.angle_between(T(a), T(b)).numpy(), ref, atol=1e-7)
    x = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64, requires_grad=True)
    ang = brdf.angle_between(x, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))
    ang.sum().backward()
    assert torch.isfinite(x.grad).all()
    assert abs(float(ang.detach())) < 1e-12


@pytest.mark.parametrize("model", MODELS)
def test_gradcheck_parameters(model):
    nrm, l, v, pd, ps, sigma = config(n=6, seed=4)
    args = [T(pd).requires_grad_(), T(ps).requires_grad_(), T(sigma).requires_grad_()]
    f = lambda a, b, c: brdf.cosine_weighted_brdf(model, T(nrm), T(l), T(v), a, b, c)
    assert torch.autograd.gradcheck(f, args)


@pytest.mark.parametrize("model", MODELS)
def test_gradcheck_directions(model):
    nrm, l, v, pd, ps, sigma = config(n=5, seed=5)
    # keep away from the n.l = 0 kink and the clamp
    keep = ((nrm * l).sum(1) > 0.2) & ((nrm * v).sum(1) > 0.2)
    nrm, l, v, pd, ps, sigma = (x[keep] for x in (nrm, l, v, pd, ps, sigma))
    args = [T(nrm).requires_grad_(), T(l).requires_grad_(), T(v).requires_grad_()]
    f = lambda n_, l_, v_: brdf.cosine_weighted_brdf(model, n_, l_, v_, T(pd), T(ps), T(sigma))
    assert torch.autograd.gradcheck(f, args)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_extremes_are_finite(model, dtype):
    """sigma at its bounds, grazing light and view, Pd 0 and 1, exact specular peak, light behind."""
    up = [0.0, 0.0, 1.0]
    graze = [1.0, 0.0, 1e-7]
    cases_l = [up, graze, [1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.0, 0.0, -1.0]]
    cases_v = [up, graze, [0.0, 1.0, 0.0], [0.0, -0.6, 0.8]]
    rows = [
        (l_, v_, pd_, s_) for l_ in cases_l for v_ in cases_v for pd_ in (0.0, 1.0) for s_ in (1e-4, 0.01, 0.6, 2.0)
    ]
    n = torch.tensor([up] * len(rows), dtype=dtype)
    l = brdf.safe_normalize(torch.tensor([r[0] for r in rows], dtype=dtype))
    v = brdf.safe_normalize(torch.tensor([r[1] for r in rows], dtype=dtype))
    pd = torch.tensor([[r[2]] * 3 for r in rows], dtype=dtype, requires_grad=True)
    ps = torch.full((len(rows), 3), 0.5, dtype=dtype, requires_grad=True)
    sigma = torch.tensor([r[3] for r in rows], dtype=dtype, requires_grad=True)
    l.requires_grad_()
    g = brdf.cosine_weighted_brdf(model, n, l, v, pd, ps, sigma)
    assert torch.isfinite(g).all()
    g.sum().backward()
    for t in (pd, ps, sigma):
        assert torch.isfinite(t.grad).all()


@pytest.mark.parametrize("model", MODELS)
def test_float32_agrees_with_float64(model):
    nrm, l, v, pd, ps, sigma = config(n=500, seed=6)
    g64 = brdf.cosine_weighted_brdf(model, T(nrm), T(l), T(v), T(pd), T(ps), T(sigma))
    f = lambda x: T(x).float()
    g32 = brdf.cosine_weighted_brdf(model, f(nrm), f(l), f(v), f(pd), f(ps), f(sigma))
    np.testing.assert_allclose(g32.double().numpy(), g64.numpy(), rtol=2e-4, atol=1e-6)


def test_lambertian_part_integrates_to_pd():
    """Monte Carlo over the hemisphere: integral of f cos_l d omega = Pd when Ps = 0 (energy)."""
    rng = np.random.default_rng(7)
    N = 400_000
    l = random_unit(N, rng, np.array([0.0, 0.0, 1.0]))
    n = np.tile([0.0, 0.0, 1.0], (N, 1))
    v = np.tile([0.0, 0.0, 1.0], (N, 1))
    g = brdf.cosine_weighted_brdf(
        "torrance_sparrow", T(n), T(l), T(v), T(np.full((N, 3), 0.7)), T(np.zeros((N, 3))), T(np.full(N, 0.2))
    )
    integral = g.numpy().mean(0) * 2 * math.pi  # uniform hemisphere pdf 1 / (2 pi)
    np.testing.assert_allclose(integral, 0.7, rtol=0.01)


def test_normalised_ward_lobe_reflects_about_ps():
    """The normalised Ward lobe with Ps = 1 and small sigma reflects close to all light at normal view."""
    rng = np.random.default_rng(8)
    N = 1_000_000
    l = random_unit(N, rng, np.array([0.0, 0.0, 1.0]))
    n = np.tile([0.0, 0.0, 1.0], (N, 1))
    v = np.tile([0.0, 0.0, 1.0], (N, 1))
    g = brdf.cosine_weighted_brdf(
        "ward_normalised", T(n), T(l), T(v), T(np.zeros((N, 3))), T(np.ones((N, 3))), T(np.full(N, 0.15))
    )
    integral = g.numpy()[:, 0].mean() * 2 * math.pi
    assert 0.9 < integral < 1.05


def test_unknown_brdf_is_a_config_error():
    with pytest.raises(ConfigError, match="fit.brdf.*'phong'"):
        brdf.specular_lobe("phong", torch.zeros(1), torch.ones(1))
    with pytest.raises(ConfigError, match="reflectance.brdf"):
        brdf.check_brdf_name("phong", "reflectance.brdf")


# ------------------------------------------------------------------ Minnaert diffuse part


def minnaert_written_out(nrm, l, v, pd, k):
    """Pd / pi (cos_l cos_v)^(k - 1) cos_l, written out (front-facing light and view)."""
    cos_l = (nrm * l).sum(1)
    cos_v = (nrm * v).sum(1)
    return pd / math.pi * ((cos_l * cos_v) ** (k - 1.0) * cos_l)[:, None]


@pytest.mark.parametrize("k", [0.6, 1.0, 1.08, 1.7])
def test_minnaert_diffuse_is_the_formula_and_k_1_is_lambert(k):
    nrm, l, v, pd, ps, sigma = config(seed=8)
    zero = np.zeros_like(ps)
    g = brdf.cosine_weighted_brdf("torrance_sparrow", T(nrm), T(l), T(v), T(pd), T(zero), T(sigma), k)
    np.testing.assert_allclose(g.numpy(), minnaert_written_out(nrm, l, v, pd, k), rtol=1e-10, atol=1e-14)
    lam = brdf.cosine_weighted_brdf("torrance_sparrow", T(nrm), T(l), T(v), T(pd), T(zero), T(sigma))
    if k == 1.0:
        np.testing.assert_array_equal(g.numpy(), lam.numpy())
    # reciprocity: f(l, v) = f(v, l), so g(l, v) / cos_l = g(v, l) / cos_v
    g_swapped = brdf.cosine_weighted_brdf("torrance_sparrow", T(nrm), T(v), T(l), T(pd), T(zero), T(sigma), k)
    cos_l, cos_v = (nrm * l).sum(1, keepdims=True), (nrm * v).sum(1, keepdims=True)
    np.testing.assert_allclose(g.numpy() / cos_l, g_swapped.numpy() / cos_v, rtol=1e-9)


def test_gradcheck_minnaert_exponent_and_parameters():
    nrm, l, v, pd, ps, sigma = config(n=6, seed=9)
    k = torch.tensor(1.15, dtype=torch.float64, requires_grad=True)
    args = [T(pd).requires_grad_(), T(ps).requires_grad_(), T(sigma).requires_grad_(), k]
    f = lambda a, b, c, e: brdf.cosine_weighted_brdf("torrance_sparrow", T(nrm), T(l), T(v), a, b, c, e)
    assert torch.autograd.gradcheck(f, args)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("k", [0.5, 1.3, 2.0])
def test_minnaert_extremes_are_finite(dtype, k):
    """Grazing and back-facing light and view at the exponent's bounds: finite values and gradients (k included)."""
    up = [0.0, 0.0, 1.0]
    dirs = [up, [1.0, 0.0, 1e-7], [1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.0, 0.0, -1.0]]
    rows = [(a, b) for a in dirs for b in dirs]
    n = torch.tensor([up] * len(rows), dtype=dtype)
    l = brdf.safe_normalize(torch.tensor([r[0] for r in rows], dtype=dtype)).requires_grad_()
    v = brdf.safe_normalize(torch.tensor([r[1] for r in rows], dtype=dtype)).requires_grad_()
    pd = torch.ones(len(rows), 3, dtype=dtype, requires_grad=True)
    e = torch.tensor(k, dtype=dtype, requires_grad=True)
    g = brdf.cosine_weighted_brdf(
        "torrance_sparrow",
        n,
        l,
        v,
        pd,
        torch.zeros(len(rows), 3, dtype=dtype),
        torch.full((len(rows),), 0.2, dtype=dtype),
        e,
    )
    assert torch.isfinite(g).all() and (g >= 0).all()
    g.sum().backward()
    for t in (l, v, pd, e):
        assert torch.isfinite(t.grad).all()


def test_minnaert_float32_agrees_with_float64():
    nrm, l, v, pd, ps, sigma = config(n=500, seed=10)
    g64 = brdf.cosine_weighted_brdf("torrance_sparrow", T(nrm), T(l), T(v), T(pd), T(ps), T(sigma), 1.2)
    f = lambda x: T(x).float()
    g32 = brdf.cosine_weighted_brdf("torrance_sparrow", f(nrm), f(l), f(v), f(pd), f(ps), f(sigma), 1.2)
    np.testing.assert_allclose(g32.double().numpy(), g64.numpy(), rtol=2e-4, atol=1e-6)


@pytest.mark.parametrize("model", brdf.BRDF_NAMES)
def test_the_specular_geometry_is_the_power_law_its_exponents_say(model):
    # the footprint spread's slope of ln G (capture.footprint_spread) reads these exponents, not the function
    ev, el = brdf.SPECULAR_GEOMETRY_EXPONENTS[model]
    cl = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    cv = torch.tensor([0.7, 0.3, 0.6], dtype=torch.float64)
    g = brdf.specular_geometry(model, cl, cv)
    if model == "lambertian":
        assert torch.all(g == 0) and (ev, el) == (0.0, 0.0)
        return
    torch.testing.assert_close(brdf.specular_geometry(model, 2 * cl, cv) / g, torch.full_like(g, 2.0**el))
    torch.testing.assert_close(brdf.specular_geometry(model, cl, 2 * cv) / g, torch.full_like(g, 2.0**ev))
