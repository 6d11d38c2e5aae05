"""The photon cache and its differentiable gather (torchrefl.transport.photon_cache): against the slow per-photon
reference, float64 gradcheck, finite values and gradients at the extremes, float32, repeatable gradients."""

import math

import numpy as np
import pytest
import torch
from conftest import photon_cache_of

from torchrefl.transport.cache_build import build_cache
from torchrefl.transport.photon_cache import (
    PhotonCache,
    indirect_radiance,
    indirect_radiance_reference,
    specular_per_unit_ps,
)
from torchrefl.transport.photon_hits import PhotonHits


def test_specular_per_unit_ps_takes_one_sigma_per_texel(photon_traced):
    """What the sigma search evaluates: with sigma (T,) each texel's entries at its own sigma, texel by texel the same
    as every texel at that one value, and Ps times it is the cache's specular light (indirect_radiance)."""
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    cache = photon_cache_of(photon_traced, 0.004)
    per_texel = specular_per_unit_ps(cache, obs.kappa, sigma)
    for t in (0, 7, s.num_texels - 1):
        one = specular_per_unit_ps(cache, obs.kappa, float(sigma[t]))
        torch.testing.assert_close(per_texel[:, t], one[:, t], rtol=1e-12, atol=1e-15)
    zero = torch.zeros_like(pd)
    spec = indirect_radiance(cache, obs.kappa, zero, ps, sigma)
    torch.testing.assert_close(ps[None] * per_texel, spec, rtol=1e-10, atol=1e-14)
    assert float(per_texel.abs().max()) > 0


def test_the_cache_reproduces_the_per_photon_sum(photon_traced):
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    assert hits.count > 500
    ref = indirect_radiance_reference(
        hits, src, pt.areas, s.normals, obs.view_dir, "torrance_sparrow", obs.kappa, pd, ps, sigma, 0.02
    )
    exact = indirect_radiance(photon_cache_of(photon_traced, 1e-12), obs.kappa, pd, ps, sigma)
    torch.testing.assert_close(exact, ref, rtol=1e-9, atol=1e-12)
    binned = indirect_radiance(photon_cache_of(photon_traced, 0.004), obs.kappa, pd, ps, sigma)
    assert float((binned - ref).abs().max() / ref.abs().max()) < 0.02
    # bins a quarter of the texel's roughness wide (the default, with the cache built at the evaluated roughness)
    # merge photons, and stay within 1 %; the same bins for a roughness halved since the cache was built, 3 %
    wide = photon_cache_of(photon_traced, 0.004, bin_per_sigma=0.25, cache_sigma=sigma.numpy())
    assert wide.entry_obs.numel() < 0.8 * photon_cache_of(photon_traced, 0.004).entry_obs.numel()
    err = lambda c, sg: float(
        (indirect_radiance(c, obs.kappa, pd, ps, sg) - ref_at(sg)).abs().max() / ref_at(sg).abs().max()
    )
    ref_at = lambda sg: indirect_radiance(photon_cache_of(photon_traced, 1e-12), obs.kappa, pd, ps, sg)
    assert err(wide, sigma) < 0.01
    assert err(wide, sigma / 2) < 0.03


@pytest.mark.parametrize(
    "linear,smoothing,smoothing_normal,specular", [(False, 0.0, 0.0, 0.0), (True, 1.0, 0.0, 0.0), (True, 1.0, 0.1, 1.0)]
)
def test_gradcheck_float64(photon_traced, linear, smoothing, smoothing_normal, specular):
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    cache = photon_cache_of(
        photon_traced,
        0.004,
        linear=linear,
        smoothing=smoothing,
        smoothing_normal=smoothing_normal,
        specular_smoothing=specular,
    )
    assert cache.entry_obs.numel() > 0
    f = lambda a, b, c: indirect_radiance(cache, obs.kappa, a, b, c)
    assert torch.autograd.gradcheck(
        f, (pd.clone().requires_grad_(), ps.clone().requires_grad_(), sigma.clone().requires_grad_())
    )


@pytest.mark.parametrize("pd_v,ps_v,sigma_v", [(0.0, 0.0, 1e-4), (1.0, 4.0, 0.6), (0.99, 0.0, 0.01)])
def test_extremes_are_finite(photon_traced, pd_v, ps_v, sigma_v):
    s, obs, pt, src, hits, *_ = photon_traced
    T = s.num_texels
    cache = photon_cache_of(photon_traced, 0.004, linear=True, smoothing=1.0)
    pd = torch.full((T, 3), pd_v, dtype=torch.float64, requires_grad=True)
    ps = torch.full((T, 1), ps_v, dtype=torch.float64, requires_grad=True)
    sigma = torch.full((T,), sigma_v, dtype=torch.float64, requires_grad=True)
    out = indirect_radiance(cache, obs.kappa, pd, ps, sigma)
    out.sum().backward()
    for x in (out, pd.grad, ps.grad, sigma.grad):
        assert torch.isfinite(x).all()


def test_texels_no_photon_reaches_get_no_indirect_light_and_finite_gradients(photon_traced):
    s, obs, pt, src, *_ = photon_traced
    T = s.num_texels
    empty = PhotonHits(
        np.zeros(0, np.int64),
        np.zeros(0, np.int64),
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        np.zeros(src.positions.shape[0] * src.num_maps, np.int64),
        0,
    )
    cache = build_cache(
        empty, src, pt.areas, s.normals, obs.view_dir, obs.valid, "torrance_sparrow", np.full(T, 0.1), 0.6, 0.02
    )
    pd = torch.full((T, 3), 0.5, dtype=torch.float64, requires_grad=True)
    out = indirect_radiance(
        cache, obs.kappa, pd, torch.full((T, 3), 0.3, dtype=torch.float64), torch.full((T,), 0.1, dtype=torch.float64)
    )
    out.sum().backward()
    assert (out == 0).all() and torch.isfinite(pd.grad).all()


def test_float32_agrees_with_float64(photon_traced):
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    c64 = photon_cache_of(photon_traced, 0.004)
    a = indirect_radiance(c64, obs.kappa, pd, ps, sigma)
    b = indirect_radiance(c64.to(torch.float32), obs.kappa.float(), pd.float(), ps.float(), sigma.float())
    torch.testing.assert_close(b.double(), a, rtol=1e-4, atol=1e-6 * float(a.abs().max()))


def test_indirect_radiance_gradients_are_bitwise_repeatable_on_two_threads():
    """Many specular entries per texel, 2 torch threads: the gradient of the reflected indirect light in sigma
    must not depend on the order threads sum the entries in (with sigma[t] instead of index_select it did,
    by up to ~1e-4 here, and LBFGS fits of the same capture drifted apart by 0.7 % in Pd)."""
    g = torch.Generator().manual_seed(0)
    P, T, E = 2, 4000, 2_000_000
    cache = PhotonCache(
        "torrance_sparrow",
        torch.rand(P, T, 3, generator=g),
        torch.randint(0, P * T, (E,), generator=g),
        torch.rand(E, generator=g) * 0.3,
        torch.rand(E, 3, generator=g),
    )
    kappa = torch.tensor(math.pi)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        grads = []
        for _ in range(4):
            pd = torch.full((T, 3), 0.5).requires_grad_(True)
            ps = torch.full((T, 3), 0.2).requires_grad_(True)
            sigma = torch.full((T,), 0.1).requires_grad_(True)
            out = indirect_radiance(cache, kappa, pd, ps, sigma)
            grads.append(torch.autograd.grad((out * out).sum(), [pd, ps, sigma]))
    finally:
        torch.set_num_threads(threads)
    for other in grads[1:]:
        for a, b in zip(grads[0], other):
            assert torch.equal(a, b)
