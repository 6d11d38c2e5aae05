"""Building the photon cache from photon hits (torchrefl.transport.cache_build): the part linear in the emitters' Pd,
the reduction one light at a time, the density kernels' needs, the all-diffuse paths left out."""

import dataclasses

import numpy as np
import pytest
import torch
from conftest import CACHE_CAMERA as CAMERA
from conftest import CACHE_LIGHTS as LIGHTS
from conftest import build_photon_cache, fold_surface, photon_cache_of, photon_tracer, point_light_observations

from torchrefl.errors import ConfigError
from torchrefl.transport import cache_build
from torchrefl.transport.cache_build import build_cache
from torchrefl.transport.light_maps import LightSources, light_sources
from torchrefl.transport.photon_cache import indirect_radiance, indirect_radiance_reference
from torchrefl.transport.photon_hits import shared_hits
from torchrefl.transport.photon_material import TexelMaterial


def test_the_linear_cache_is_exact_at_the_traced_pd(photon_traced):
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    a = indirect_radiance(photon_cache_of(photon_traced, 0.004), obs.kappa, pd, ps, sigma)
    b = indirect_radiance(photon_cache_of(photon_traced, 0.004, linear=True), obs.kappa, pd, ps, sigma)
    torch.testing.assert_close(b, a, rtol=1e-9, atol=1e-9 * float(a.abs().max()))


def test_only_a_cache_linear_in_pd_keeps_the_smoother(photon_traced):
    """The density kernel serves the part linear in the emitters' Pd (irradiance_at): a cache without that part
    (the photon level's) does not keep it (a copy per cache: 0.4 GB on the fold); the smoothed H0 is the same."""
    plain = photon_cache_of(photon_traced, 0.004, smoothing=1.5)
    linear = photon_cache_of(photon_traced, 0.004, linear=True, smoothing=1.5)
    assert plain.linear is None and plain.smoother is None
    assert linear.smoother is not None
    pd = photon_traced[5]
    torch.testing.assert_close(plain.irradiance_at(pd), linear.irradiance_at(pd), rtol=1e-9, atol=1e-12)


def test_the_cache_reduced_one_light_at_a_time_is_the_cache_of_all_at_once(photon_traced, monkeypatch):
    """build_cache without a part linear in Pd reduces the hits light by light (to bound memory): bit for bit the
    cache of all the hits reduced at once, smoothed and spread, with the same counts."""
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    args = (hits, src, pt.areas, s.normals, obs.view_dir, torch.ones(obs.valid.shape, dtype=torch.bool))
    args = (*args, "torrance_sparrow", sigma.numpy(), 10.0, 0.02)
    kwargs = dict(dtype=torch.float32, smoothing=1.5, grid=(s.neighbours, s.normals), smoothing_normal=0.1)
    kwargs.update(specular_smoothing=1.0, bin_per_sigma=0.25)
    by_light = build_cache(*args, **kwargs)
    monkeypatch.setattr(cache_build, "_several_lights", lambda *a: False)  # every light's hits at once
    at_once = build_cache(*args, **kwargs)
    assert len(np.unique(hits.source // src.num_maps)) == 2 and by_light.entry_obs.numel() > 100
    for name in ("irradiance", "entry_obs", "entry_theta_h", "entry_weight"):
        assert getattr(by_light, name).equal(getattr(at_once, name)), name
    assert by_light.stats == at_once.stats


def test_images_sharing_lights_reduce_their_lights_hits_without_copying_them_all(photon_traced, monkeypatch):
    """Images that share a light (mesh_views: several cameras per light) reduce that light's hits, seen from their own
    camera: the cache of build_cache(image_light=...) is bit for bit the cache of the hits copied for every image
    (shared_hits) and reduced all at once, and it counts the hits traced, not their copies."""
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    K, T = src.num_maps, s.num_texels
    image_light = np.array([0, 1, 1, 0, 1])  # five images of the two traced lights, in no particular order
    images = LightSources(src.positions[image_light], src.weights, src.intensity[image_light])
    cameras = np.array(
        [[0.0, 0.0, 400.0], [80.0, 30.0, 380.0], [-60.0, 50.0, 390.0], [20.0, -90.0, 370.0], [5, 5, 420]]
    )
    view = cameras[:, None, :] - s.positions.double().numpy()[None]
    view = torch.from_numpy(view / np.linalg.norm(view, axis=-1, keepdims=True))  # (P, T, 3): each image's own camera
    keep = torch.rand(5, T, generator=torch.Generator().manual_seed(1)) > 0.2
    args = (images, pt.areas, s.normals, view, keep, "torrance_sparrow", sigma.numpy(), 10.0, 0.02)
    kwargs = dict(dtype=torch.float32, smoothing=1.5, grid=(s.neighbours, s.normals), smoothing_normal=0.1)
    kwargs.update(specular_smoothing=1.0, bin_per_sigma=0.25)
    lazily = build_cache(hits, *args, image_light=image_light, **kwargs)
    monkeypatch.setattr(cache_build, "_several_lights", lambda *a: False)  # every image's copies at once
    copied = build_cache(shared_hits(hits, image_light, K), *args, **kwargs)
    assert lazily.entry_obs.numel() > 100 and lazily.irradiance.shape == (5, T, 3)
    assert not lazily.irradiance[1].equal(torch.zeros(T, 3)) and lazily.irradiance[1].equal(lazily.irradiance[2])
    for name in ("irradiance", "entry_obs", "entry_theta_h", "entry_weight"):
        assert getattr(lazily, name).equal(getattr(copied, name)), name
    p0, p3 = (lazily.entry_obs // T == p for p in (0, 3))  # one light, two cameras: different view-dependent entries
    theta0, theta3 = lazily.entry_theta_h[p0], lazily.entry_theta_h[p3]
    assert p0.any() and p3.any() and (theta0.shape != theta3.shape or not theta0.equal(theta3))
    assert lazily.stats["stored_hits"] == hits.count and copied.stats["stored_hits"] > 2 * hits.count


def test_the_linear_cache_follows_the_emitters_pd():
    """Traced at Pd 0.6, evaluated at Pd 0.3: against a re-trace at 0.3 the linear cache (exact for the
    last bounce) errs far less than the same cache held fixed."""
    s = fold_surface(16, 32)
    T = s.num_texels
    obs = point_light_observations(s.normals, s.positions, LIGHTS[:1], CAMERA, intensity=1e4)
    pt = photon_tracer(s, "lambertian")
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


def test_normal_aware_smoothing_needs_the_normals(photon_traced):
    s = photon_traced[0]
    with pytest.raises(ConfigError, match="smoothing_normal"):
        build_photon_cache(photon_traced, smoothing=1.0, grid=(s.neighbours,), smoothing_normal=0.1)


def test_specular_spreading_needs_the_grid(photon_traced):
    with pytest.raises(ConfigError, match="specular_smoothing"):
        build_photon_cache(photon_traced, specular_smoothing=1.0)


def test_leaving_out_the_all_diffuse_paths_keeps_exactly_the_flagged_photons(photon_traced):
    """build_cache(diffuse_paths=False) (photon.diffuse_paths: radiosity): H sums only the photons whose path had a
    specular scattering, by the per-photon reference restricted to them; the specular entries keep every photon."""
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    flagged = hits.specular_path
    assert 0 < flagged.sum() < hits.count
    build = lambda h, **kw: build_photon_cache(photon_traced, h, theta_bin=1e-12, bin_per_sigma=0.0, **kw)
    left_out = build(hits, diffuse_paths=False)
    only_flagged = hits.take(np.flatnonzero(flagged))
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


def test_a_trace_that_stores_only_specular_paths_gives_the_gathering_cache_it_gave_before(photon_traced):
    """With the all-diffuse paths taken from the radiosity level and their specular reflection gathered
    (diffuse_paths=False, specular_paths_only=True), the other hits carry no weight: a trace that stores only the
    hits of paths with a specular scattering stores exactly those of the full trace (same photons), far fewer, and
    the cache built from them is bit for bit the full trace's."""
    s, obs, pt, src, full, pd, ps, sigma = photon_traced  # conftest.trace_photons: 3 000 photons per map, seed 0
    mat = TexelMaterial.from_tensors(pd, ps, sigma)
    intensity = np.repeat(src.intensity, src.num_maps, 0)
    kept = pt.trace(src.positions.reshape(-1, 3), intensity, 3000, mat, seed=0, specular_paths_only=True)
    wanted = np.flatnonzero(full.specular_path)
    assert 0 < kept.count == wanted.size < 0.8 * full.count
    for name in ("source", "texel", "direction", "power", "emitter", "density_weight"):
        assert np.array_equal(getattr(kept, name), np.take(getattr(full, name), wanted, axis=0)), name
    assert kept.rays == full.rays and np.array_equal(kept.emitted, full.emitted)
    args = (src, pt.areas, s.normals, obs.view_dir, obs.valid, "torrance_sparrow", sigma.numpy(), 10.0, 0.02)
    kwargs = dict(smoothing=1.0, grid=(s.neighbours, s.normals), specular_smoothing=1.0)
    kwargs.update(diffuse_paths=False, specular_paths_only=True)
    a, b = build_cache(full, *args, **kwargs), build_cache(kept, *args, **kwargs)
    assert a.entry_obs.numel() > 100 and float(a.irradiance.abs().sum()) > 0
    for name in ("irradiance", "entry_obs", "entry_theta_h", "entry_weight"):
        assert getattr(a, name).equal(getattr(b, name)), name
