"""The photon cache and its differentiable gather: against the slow per-photon reference, float64
gradcheck, finite values and gradients at the extremes, light maps of moving lights."""

import math

import numpy as np
import pytest
import torch
from conftest import fold_surface, point_light_observations

from torchrefl.core.rays import RayTracer
from torchrefl.errors import ConfigError
from torchrefl.transport import photon_cache
from torchrefl.transport.photon_cache import (
    PhotonCache,
    build_cache,
    indirect_radiance,
    indirect_radiance_reference,
    light_sources,
    specular_per_unit_ps,
    texel_light_positions,
)
from torchrefl.transport.photon_density import smooth_on_grid, spread_on_grid
from torchrefl.transport.photon_material import TexelMaterial
from torchrefl.transport.photon_trace import PhotonTracer

LIGHTS = np.array([[-40.0, 5.0, 50.0], [-20.0, -10.0, 70.0]])
CAMERA = np.array([-150.0, 0.0, 150.0])


@pytest.fixture(scope="module")
def traced():
    s = fold_surface(8, 16)
    T = s.num_texels
    obs = point_light_observations(s.normals, s.positions, LIGHTS, CAMERA, intensity=1e4)
    pt = PhotonTracer(
        RayTracer(s.mesh_vertices, s.mesh_faces),
        s.texel_index.numpy(),
        s.positions.numpy(),
        s.normals.numpy(),
        "torrance_sparrow",
        offset=1e-3,
    )
    src = light_sources(s, obs, 4)
    g = torch.Generator().manual_seed(0)
    pd = 0.2 + 0.6 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    ps = 0.1 + 0.5 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    sigma = 0.05 + 0.3 * torch.rand(T, generator=g, dtype=torch.float64)
    return s, obs, pt, src, trace(pt, src, pd, ps, sigma, seed=0), pd, ps, sigma


def trace(pt, src, pd, ps, sigma, seed):
    """3,000 photons per light map through the texels' materials."""
    material = TexelMaterial.from_tensors(pd, ps, sigma)
    return pt.trace(src.positions.reshape(-1, 3), np.repeat(src.intensity, src.num_maps, 0), 3000, material, seed=seed)


def cache_of(
    traced,
    theta_bin,
    sigma_max=10.0,
    linear=False,
    smoothing=0.0,
    smoothing_normal=0.0,
    specular_smoothing=0.0,
    bin_per_sigma=0.0,
    cache_sigma=None,
):
    s, obs, pt, src, hits, pd, ps, sigma = traced
    keep = torch.ones(obs.valid.shape, dtype=torch.bool)
    cache_sigma = np.full(s.num_texels, 1.0) if cache_sigma is None else cache_sigma
    return build_cache(
        hits,
        src,
        pt.areas,
        s.normals,
        obs.view_dir,
        keep,
        "torrance_sparrow",
        cache_sigma,
        sigma_max,
        0.02,
        theta_bin=theta_bin,
        bin_per_sigma=bin_per_sigma,
        emitter_pd=pd.numpy() if linear else None,
        smoothing=smoothing,
        grid=(s.neighbours, s.normals),
        smoothing_normal=smoothing_normal,
        specular_smoothing=specular_smoothing,
    )


def test_the_linear_cache_is_exact_at_the_traced_pd(traced):
    s, obs, pt, src, hits, pd, ps, sigma = traced
    a = indirect_radiance(cache_of(traced, 0.004), obs.kappa, pd, ps, sigma)
    b = indirect_radiance(cache_of(traced, 0.004, linear=True), obs.kappa, pd, ps, sigma)
    torch.testing.assert_close(b, a, rtol=1e-9, atol=1e-9 * float(a.abs().max()))


def test_only_a_cache_linear_in_pd_keeps_the_smoother(traced):
    """The density kernel serves the part linear in the emitters' Pd (irradiance_at): a cache without that part
    (the photon level's) does not keep it (a copy per cache: 0.4 GB on the fold); the smoothed H0 is the same."""
    plain = cache_of(traced, 0.004, smoothing=1.5)
    linear = cache_of(traced, 0.004, linear=True, smoothing=1.5)
    assert plain.linear is None and plain.smoother is None
    assert linear.smoother is not None
    pd = traced[5]
    torch.testing.assert_close(plain.irradiance_at(pd), linear.irradiance_at(pd), rtol=1e-9, atol=1e-12)


def test_the_cache_reduced_one_light_at_a_time_is_the_cache_of_all_at_once(traced, monkeypatch):
    """build_cache without a part linear in Pd reduces the hits light by light (to bound memory): bit for bit the
    cache of all the hits reduced at once, smoothed and spread, with the same counts."""
    s, obs, pt, src, hits, pd, ps, sigma = traced
    args = (hits, src, pt.areas, s.normals, obs.view_dir, torch.ones(obs.valid.shape, dtype=torch.bool))
    args = (*args, "torrance_sparrow", sigma.numpy(), 10.0, 0.02)
    kwargs = dict(dtype=torch.float32, smoothing=1.5, grid=(s.neighbours, s.normals), smoothing_normal=0.1)
    kwargs.update(specular_smoothing=1.0, bin_per_sigma=0.25)
    by_light = build_cache(*args, **kwargs)
    monkeypatch.setattr(photon_cache, "_several_lights", lambda *a: False)  # every light's hits at once
    at_once = build_cache(*args, **kwargs)
    assert len(np.unique(hits.source // src.num_maps)) == 2 and by_light.entry_obs.numel() > 100
    for name in ("irradiance", "entry_obs", "entry_theta_h", "entry_weight"):
        assert getattr(by_light, name).equal(getattr(at_once, name)), name
    assert by_light.stats == at_once.stats


def test_specular_per_unit_ps_takes_one_sigma_per_texel(traced):
    """What the sigma search evaluates: with sigma (T,) each texel's entries at its own sigma, texel by texel the same
    as every texel at that one value, and Ps times it is the cache's specular light (indirect_radiance)."""
    s, obs, pt, src, hits, pd, ps, sigma = traced
    cache = cache_of(traced, 0.004)
    per_texel = specular_per_unit_ps(cache, obs.kappa, sigma)
    for t in (0, 7, s.num_texels - 1):
        one = specular_per_unit_ps(cache, obs.kappa, float(sigma[t]))
        torch.testing.assert_close(per_texel[:, t], one[:, t], rtol=1e-12, atol=1e-15)
    zero = torch.zeros_like(pd)
    spec = indirect_radiance(cache, obs.kappa, zero, ps, sigma)
    torch.testing.assert_close(ps[None] * per_texel, spec, rtol=1e-10, atol=1e-14)
    assert float(per_texel.abs().max()) > 0


def test_the_linear_cache_follows_the_emitters_pd():
    """Traced at Pd 0.6, evaluated at Pd 0.3: against a re-trace at 0.3 the linear cache (exact for the
    last bounce) errs far less than the same cache held fixed."""
    s = fold_surface(16, 32)
    T = s.num_texels
    obs = point_light_observations(s.normals, s.positions, LIGHTS[:1], CAMERA, intensity=1e4)
    pt = PhotonTracer(
        RayTracer(s.mesh_vertices, s.mesh_faces),
        s.texel_index.numpy(),
        s.positions.numpy(),
        s.normals.numpy(),
        "lambertian",
        offset=1e-3,
    )
    src = light_sources(s, obs, 1)

    def cache(pd_value, linear, seed):
        pd = torch.full((T, 3), pd_value, dtype=torch.float64)
        hits = pt.trace(
            src.positions.reshape(-1, 3),
            src.intensity,
            400_000,
            TexelMaterial.from_tensors(pd, torch.zeros(T, 3), torch.full((T,), 0.1)),
            seed=seed,
        )
        return build_cache(
            hits,
            src,
            pt.areas,
            s.normals,
            obs.view_dir,
            obs.valid,
            "lambertian",
            np.full(T, 0.1),
            0.6,
            0.02,
            emitter_pd=pd.numpy() if linear else None,
            smoothing=1.0,
            grid=(s.neighbours,),
        )

    new = torch.full((T, 3), 0.3, dtype=torch.float64)
    truth = cache(0.3, False, 1).irradiance_at(new)
    rel = lambda c: float((c.irradiance_at(new) - truth).norm() / truth.norm())
    linear, fixed = rel(cache(0.6, True, 2)), rel(cache(0.6, False, 2))
    assert fixed > 0.8 and linear < 0.15, (linear, fixed)


def test_the_cache_reproduces_the_per_photon_sum(traced):
    s, obs, pt, src, hits, pd, ps, sigma = traced
    assert hits.count > 500
    ref = indirect_radiance_reference(
        hits, src, pt.areas, s.normals, obs.view_dir, "torrance_sparrow", obs.kappa, pd, ps, sigma, 0.02
    )
    exact = indirect_radiance(cache_of(traced, 1e-12), obs.kappa, pd, ps, sigma)
    torch.testing.assert_close(exact, ref, rtol=1e-9, atol=1e-12)
    binned = indirect_radiance(cache_of(traced, 0.004), obs.kappa, pd, ps, sigma)
    assert float((binned - ref).abs().max() / ref.abs().max()) < 0.02
    # bins a quarter of the texel's roughness wide (the default, with the cache built at the evaluated roughness)
    # merge photons, and stay within 1 %; the same bins for a roughness halved since the cache was built, 3 %
    wide = cache_of(traced, 0.004, bin_per_sigma=0.25, cache_sigma=sigma.numpy())
    assert wide.entry_obs.numel() < 0.8 * cache_of(traced, 0.004).entry_obs.numel()
    err = lambda c, sg: float(
        (indirect_radiance(c, obs.kappa, pd, ps, sg) - ref_at(sg)).abs().max() / ref_at(sg).abs().max()
    )
    ref_at = lambda sg: indirect_radiance(cache_of(traced, 1e-12), obs.kappa, pd, ps, sg)
    assert err(wide, sigma) < 0.01
    assert err(wide, sigma / 2) < 0.03


@pytest.mark.parametrize(
    "linear,smoothing,smoothing_normal,specular", [(False, 0.0, 0.0, 0.0), (True, 1.0, 0.0, 0.0), (True, 1.0, 0.1, 1.0)]
)
def test_gradcheck_float64(traced, linear, smoothing, smoothing_normal, specular):
    s, obs, pt, src, hits, pd, ps, sigma = traced
    cache = cache_of(
        traced,
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
def test_extremes_are_finite(traced, pd_v, ps_v, sigma_v):
    s, obs, pt, src, hits, *_ = traced
    T = s.num_texels
    cache = cache_of(traced, 0.004, linear=True, smoothing=1.0)
    pd = torch.full((T, 3), pd_v, dtype=torch.float64, requires_grad=True)
    ps = torch.full((T, 1), ps_v, dtype=torch.float64, requires_grad=True)
    sigma = torch.full((T,), sigma_v, dtype=torch.float64, requires_grad=True)
    out = indirect_radiance(cache, obs.kappa, pd, ps, sigma)
    out.sum().backward()
    for x in (out, pd.grad, ps.grad, sigma.grad):
        assert torch.isfinite(x).all()


def test_texels_no_photon_reaches_get_no_indirect_light_and_finite_gradients(traced):
    s, obs, pt, src, *_ = traced
    T = s.num_texels
    from torchrefl.transport.photon_hits import PhotonHits

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


def test_float32_agrees_with_float64(traced):
    s, obs, pt, src, hits, pd, ps, sigma = traced
    c64 = cache_of(traced, 0.004)
    a = indirect_radiance(c64, obs.kappa, pd, ps, sigma)
    b = indirect_radiance(c64.to(torch.float32), obs.kappa.float(), pd.float(), ps.float(), sigma.float())
    torch.testing.assert_close(b.double(), a, rtol=1e-4, atol=1e-6 * float(a.abs().max()))


def test_moving_lights_get_light_maps_that_interpolate_by_column():
    """On a co-rotating rig each column sees the light from its own position: maps sit at evenly spaced
    columns, the outer ones on the outermost columns, with weights summing to one, and their positions are the
    lights the texels saw."""
    s = fold_surface(4, 16)
    H, W = s.grid_shape
    col = s.texel_index % W
    # a light that moves with the column (rotates about the fold's y axis)
    angle = (col.double() - 8) * 0.05
    L = torch.stack([-60 * torch.sin(angle) - 30, torch.zeros_like(angle), 60 * torch.cos(angle)], -1)
    obs = point_light_observations(s.normals, s.positions, np.zeros((1, 3)), CAMERA)
    to = L[None] - s.positions[None]
    dist = to.norm(dim=-1)
    obs.light_dir, obs.falloff = to / dist[..., None], 1.0 / dist**2
    torch.testing.assert_close(torch.as_tensor(texel_light_positions(s, obs))[0], L)
    src = light_sources(s, obs, 4)
    assert src.positions.shape == (1, 4, 3)
    np.testing.assert_allclose(src.weights.sum(0), 1.0)
    # each map's position is the light of the texels in its column (columns 0, 5, 10, 15 of 16), where its
    # weight is 1
    for k in range(4):
        cols = col == 5 * k
        np.testing.assert_allclose(src.positions[0, k], L[cols].mean(0).numpy(), atol=1e-9)
        np.testing.assert_allclose(src.weights[k, cols.numpy()], 1.0, atol=1e-12)
    fixed = point_light_observations(s.normals, s.positions, LIGHTS, CAMERA)
    one = light_sources(s, fixed, 4)
    assert one.positions.shape == (2, 1, 3) and np.allclose(one.positions[:, 0], LIGHTS)


def test_normal_aware_smoothing_does_not_gather_across_a_fold():
    """A field constant on each side of a 90 degree fold: the plain Gaussian mixes the sides in the columns next to
    the fold, the normal-aware kernel keeps each side's value; on one side alone both are the same Gaussian."""
    s = fold_surface(12, 24)
    floor = s.normals[:, 2] > 0.5
    values = torch.where(floor, 1.0, 3.0).to(torch.float64)[None, :, None].expand(2, -1, 3).clone()
    plain = smooth_on_grid(values, s.texel_index, s.grid_shape, 1.0)
    aware = smooth_on_grid(values, s.texel_index, s.grid_shape, 1.0, s.normals, 0.1)
    torch.testing.assert_close(aware, values, rtol=0, atol=1e-12)
    col = s.texel_index % s.grid_shape[1]
    next_to_fold = (col == 11) | (col == 12)
    assert (plain[0, next_to_fold, 0] - values[0, next_to_fold, 0]).abs().min() > 0.1
    # a smooth field on one plate: the normal factor is 1 there, so the result is the normalised Gaussian
    ramp = (s.positions[:, 1:2] * 0.1 + 2.0).expand(-1, 3)[None]
    on_floor = lambda x: x[:, floor & (col < 8)]
    torch.testing.assert_close(
        on_floor(smooth_on_grid(ramp, s.texel_index, s.grid_shape, 1.0, s.normals, 0.1)),
        on_floor(smooth_on_grid(ramp, s.texel_index, s.grid_shape, 1.0)),
        rtol=1e-10,
        atol=1e-12,
    )


def test_normal_aware_smoothing_needs_the_normals(traced):
    s, obs, pt, src, hits, pd, ps, sigma = traced
    keep = torch.ones(obs.valid.shape, dtype=torch.bool)
    with pytest.raises(ConfigError, match="smoothing_normal"):
        build_cache(
            hits,
            src,
            pt.areas,
            s.normals,
            obs.view_dir,
            keep,
            "torrance_sparrow",
            np.full(s.num_texels, 1.0),
            10.0,
            0.02,
            smoothing=1.0,
            grid=(s.neighbours,),
            smoothing_normal=0.1,
        )


def test_spreading_keeps_a_constant_field_and_does_not_cross_the_fold():
    """One unit entry per texel spread with the normalised kernel: every texel receives exactly 1 (interior and
    border alike); with the normal test nothing crosses the fold; copies stay with their light."""
    s = fold_surface(10, 20)
    T = s.num_texels
    for normals, ns in ((None, 0.0), (s.normals, 0.1)):
        obs = np.concatenate([np.arange(T), T + np.arange(T)])  # lights 0 and 1
        to, src, w = spread_on_grid(obs, T, s.neighbours, 1.0, normals, ns)
        received = np.bincount(to, weights=w, minlength=2 * T)
        np.testing.assert_allclose(received, 1.0, rtol=1e-12)
        assert ((to // T) == (obs[src] // T)).all()
    floor = (s.normals[:, 2] > 0.5).numpy()
    to, src, w = spread_on_grid(np.flatnonzero(floor), T, s.neighbours, 1.0, s.normals, 0.1)
    assert floor[to[w > 1e-12]].all()
    to, src, w = spread_on_grid(np.flatnonzero(floor), T, s.neighbours, 1.0)
    assert not floor[to[w > 1e-3]].all()  # the plain kernel does cross


def test_specular_spreading_needs_the_grid(traced):
    s, obs, pt, src, hits, pd, ps, sigma = traced
    keep = torch.ones(obs.valid.shape, dtype=torch.bool)
    with pytest.raises(ConfigError, match="specular_smoothing"):
        build_cache(
            hits,
            src,
            pt.areas,
            s.normals,
            obs.view_dir,
            keep,
            "torrance_sparrow",
            np.full(s.num_texels, 1.0),
            10.0,
            0.02,
            specular_smoothing=1.0,
        )


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


def test_leaving_out_the_all_diffuse_paths_keeps_exactly_the_flagged_photons(traced):
    """build_cache(diffuse_paths=False) (photon.diffuse_paths: radiosity): H sums only the photons whose path had a
    specular scattering, by the per-photon reference restricted to them; the specular entries keep every photon."""
    import dataclasses

    s, obs, pt, src, hits, pd, ps, sigma = traced
    flagged = hits.specular_path
    assert 0 < flagged.sum() < hits.count
    keep = torch.ones(obs.valid.shape, dtype=torch.bool)
    build = lambda h, **kw: build_cache(
        h,
        src,
        pt.areas,
        s.normals,
        obs.view_dir,
        keep,
        "torrance_sparrow",
        np.full(s.num_texels, 1.0),
        10.0,
        0.02,
        theta_bin=1e-12,
        bin_per_sigma=0.0,
        **kw,
    )
    left_out = build(hits, diffuse_paths=False)
    sub = lambda a: a[flagged]
    only_flagged = dataclasses.replace(
        hits,
        source=sub(hits.source),
        texel=sub(hits.texel),
        direction=sub(hits.direction),
        power=sub(hits.power),
        emitter=sub(hits.emitter),
        diffuse_per_pd=sub(hits.diffuse_per_pd),
        specular_path=sub(flagged),
        density_weight=sub(hits.density_weight),
    )
    zero = torch.zeros_like(pd)
    ref = indirect_radiance_reference(
        only_flagged,
        src,
        pt.areas,
        s.normals,
        obs.view_dir,
        "torrance_sparrow",
        obs.kappa,
        pd,
        zero[:, :1].expand(-1, 3),
        sigma,
        0.02,
    )
    torch.testing.assert_close(indirect_radiance(left_out, obs.kappa, pd, zero, sigma), ref, rtol=1e-9, atol=1e-12)
    full = build(hits)
    torch.testing.assert_close(left_out.entry_weight, full.entry_weight)
    assert float(left_out.irradiance.sum()) < float(full.irradiance.sum())
    # linear emitters: the Pd-linear part is restricted the same way, exact at the traced Pd
    lin = build(hits, diffuse_paths=False, emitter_pd=pd.numpy())
    torch.testing.assert_close(lin.irradiance_at(pd), left_out.irradiance, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="specular_path"):
        build(dataclasses.replace(hits, specular_path=None), diffuse_paths=False)


def test_map_weights_reproduce_cubics_and_sum_to_one():
    """Cubic Lagrange weights over the four nearest maps reproduce any cubic in the map coordinate exactly, the
    extrapolation half a map step past the outer maps included, and each texel's weights sum to one; fewer maps
    fall back to the polynomial they can hold; order 1 is the tent between the two nearest."""
    from torchrefl.transport.photon_cache import map_weights

    rng = np.random.default_rng(0)
    for K, degree in ((8, 3), (4, 3), (3, 2), (2, 1)):
        s = np.concatenate([np.linspace(-0.5, K - 0.5, 101), rng.uniform(0, K - 1, 50)])
        w = map_weights(s, K)
        assert w.shape == (K, s.size)
        np.testing.assert_allclose(w.sum(0), 1.0, atol=1e-12)
        c = rng.normal(size=degree + 1)
        f = lambda x: np.polyval(c, x)
        np.testing.assert_allclose((w * f(np.arange(K))[:, None]).sum(0), f(s), atol=1e-10)
        assert int((np.abs(w) > 0).sum(0).max()) <= min(4, K)
        inside = (s >= 0) & (s <= K - 1)
        assert float(np.sqrt((w[:, inside] ** 2).sum(0)).max()) < 1.09  # little gain on the maps' noise
    np.testing.assert_array_equal(map_weights(np.array([0.3, 2.0]), 1), np.ones((1, 2)))
    tent = map_weights(np.array([1.25, 2.0, 5.5]), 8, order=1)
    expect = np.zeros((8, 3))
    expect[1, 0], expect[2, 0], expect[2, 1], expect[5, 2], expect[6, 2] = 0.75, 0.25, 1.0, 0.5, 0.5
    np.testing.assert_allclose(tent, expect, atol=1e-12)


def test_a_field_that_bends_with_the_light_is_interpolated_within_a_fraction_of_the_tents_error():
    """Indirect light that varies smoothly but not linearly across the columns (here exp of the map coordinate):
    the cubic weights' error is far below the tent's, the error Object E's lower plate showed at 8 maps."""
    from torchrefl.transport.photon_cache import map_weights

    K = 8
    s = np.linspace(0, K - 1, 400)
    f = lambda x: np.exp(0.3 * x)
    cubic = np.abs((map_weights(s, K) * f(np.arange(K))[:, None]).sum(0) / f(s) - 1).max()
    tent = np.abs((map_weights(s, K, order=1) * f(np.arange(K))[:, None]).sum(0) / f(s) - 1).max()
    assert cubic < 0.1 * tent, (cubic, tent)
