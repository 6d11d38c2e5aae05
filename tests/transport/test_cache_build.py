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
from torchrefl.transport.light_maps import light_sources
from torchrefl.transport.photon_cache import indirect_radiance, indirect_radiance_reference
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
