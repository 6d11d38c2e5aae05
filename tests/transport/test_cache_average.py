"""Two traces' caches as one (torchrefl.transport.cache_average): the mean of their predictions, with the part
that has no photon noise taken from the newer one."""

import numpy as np
import torch
from conftest import photon_cache_of, trace_photons

from torchrefl.transport.cache_average import average_caches
from torchrefl.transport.photon_cache import PhotonCache, indirect_radiance, specular_per_unit_ps
from torchrefl.transport.specular_bins import merge_entries


def test_an_average_of_two_traces_predicts_the_mean_of_their_predictions(photon_traced):
    """average_caches: the mean of the two caches' indirect light at any parameters (their diffuse parts exactly,
    the specular part within the theta_h bins' merge error), with fewer entries than the two together."""
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    other = trace_photons(pt, src, pd, ps, sigma, seed=1)
    a = photon_cache_of(photon_traced, 0.004, linear=True, smoothing=1.5, bin_per_sigma=0.25, cache_sigma=sigma.numpy())
    b = photon_cache_of(
        (*photon_traced[:4], other, pd, ps, sigma),
        0.004,
        linear=True,
        smoothing=1.5,
        bin_per_sigma=0.25,
        cache_sigma=sigma.numpy(),
    )
    both = average_caches(a, b, sigma.numpy())
    assert both.stats["averaged_traces"] == 2
    assert both.stats["averaged_entries"] == both.entry_obs.numel() < a.entry_obs.numel() + b.entry_obs.numel()
    g = torch.Generator().manual_seed(3)
    pd2 = 0.1 + 0.8 * torch.rand(pd.shape, generator=g, dtype=torch.float64)  # away from the traced Pd
    zero = torch.zeros_like(ps)
    diffuse = lambda c: indirect_radiance(c, obs.kappa, pd2, zero, sigma)
    torch.testing.assert_close(diffuse(both), 0.5 * (diffuse(a) + diffuse(b)), rtol=1e-9, atol=1e-12)
    specular = lambda c: specular_per_unit_ps(c, obs.kappa, sigma)
    expected = 0.5 * (specular(a) + specular(b))
    error = (specular(both) - expected).abs()
    assert float(expected.abs().max()) > 0
    assert float(error.max()) < 0.02 * float(expected.abs().max())
    assert float(error.sum()) < 0.005 * float(expected.abs().sum())


def test_the_part_without_photon_noise_is_the_newer_caches_not_averaged(photon_traced):
    """With photon.diffuse_paths: radiosity the cache's irradiance holds the radiosity level's solution at the Pd of
    its trace (exact_irradiance): the average keeps the newer one instead of lagging half a refit behind."""
    s, obs, pt, src, hits, pd, ps, sigma = photon_traced
    a = photon_cache_of(photon_traced, 0.004)
    b = photon_cache_of(photon_traced, 0.004)
    photons = a.irradiance.clone()
    a.exact_irradiance, b.exact_irradiance = torch.full_like(photons, 1.0), torch.full_like(photons, 3.0)
    a.irradiance, b.irradiance = photons + 1.0, photons + 3.0
    both = average_caches(a, b, sigma.numpy())
    torch.testing.assert_close(both.irradiance, photons + 3.0)
    assert both.exact_irradiance.equal(b.exact_irradiance)


def test_the_entries_merged_one_light_at_a_time_are_those_of_one_merge_of_all():
    """average_caches merges the specular entries light by light (to bound memory): bit for bit the entries of
    merge_entries over both caches' entries at once (a's then b's, at half weight), for caches whose entries are
    in no particular order, one without entries of a light, and a light with no entries in either."""
    P, T, M = 4, 50, 3000
    rng = np.random.default_rng(5)
    sigma = rng.uniform(0.05, 0.4, T)

    def cache(lights):
        obs = torch.from_numpy(rng.choice(lights, M) * T + rng.integers(0, T, M))
        theta = torch.from_numpy(rng.uniform(0.0, 0.6, M)).float()
        weight = torch.from_numpy(rng.uniform(-0.1, 1.0, (M, 3))).float()
        return PhotonCache("torrance_sparrow", torch.zeros(P, T, 3), obs, theta, weight)

    a, b = cache([0, 1, 3]), cache([1, 3])
    both = average_caches(a, b, sigma)
    weight = 0.5 * torch.cat([a.entry_weight, b.entry_weight])
    obs, theta, w = merge_entries(
        torch.cat([a.entry_obs, b.entry_obs]).numpy(),
        torch.cat([a.entry_theta_h, b.entry_theta_h]).double().numpy(),
        weight.double().numpy().T,
        sigma,
        T,
    )
    assert both.entry_obs.dtype == torch.int64 and both.entry_weight.dtype == torch.float32
    assert both.entry_obs.equal(torch.from_numpy(obs))
    assert both.entry_theta_h.equal(torch.from_numpy(theta).float())
    assert both.entry_weight.equal(torch.from_numpy(w).float())
    assert set((both.entry_obs // T).tolist()) == {0, 1, 3}
