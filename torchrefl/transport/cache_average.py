"""Two photon traces' caches as one: the photon level's refreshes from the third on fit the mean of the new trace
and the previous one (half the photon noise, no extra tracing; torchrefl.transport.levels.photon)."""

from __future__ import annotations

import numpy as np
import torch

from torchrefl.transport.photon_cache import PhotonCache
from torchrefl.transport.specular_bins import BIN_PER_SIGMA, THETA_BIN, merge_entries


def average_caches(
    a: PhotonCache, b: PhotonCache, sigma, theta_bin: float = THETA_BIN, bin_per_sigma: float = BIN_PER_SIGMA
) -> PhotonCache:
    """The cache of two independent traces' photons at half weight each: the mean of their photon irradiance and of
    their parts linear in Pd (the part without photon noise, exact_irradiance, is b's: the newer), and both traces'
    specular entries merged again into the theta_h bins of roughness sigma (T,) (specular_bins.merge_entries), so
    the entries do not double. Both caches must share the smoother. The stats are
    b's (the newer trace's) with `averaged_traces` and `averaged_entries` (the merged entries) added."""
    if (a.linear is None) != (b.linear is None):
        raise ValueError("average_caches: one cache is linear in the emitters' Pd and the other is not")
    T = a.irradiance.shape[1]
    entries = [torch.cat([x.entry_obs for x in (a, b)]), torch.cat([x.entry_theta_h for x in (a, b)])]
    weight = 0.5 * torch.cat([a.entry_weight, b.entry_weight])
    if entries[0].numel():
        dt, dev = weight.dtype, weight.device
        obs, theta, w = merge_entries(
            entries[0].cpu().numpy(),
            entries[1].cpu().double().numpy(),
            weight.cpu().double().numpy().T,
            np.asarray(sigma, dtype=np.float64),
            T,
            theta_bin,
            bin_per_sigma,
        )
        entries = [torch.from_numpy(obs).to(dev), torch.from_numpy(theta).to(dev, dt)]
        weight = torch.from_numpy(w).to(dev, dt)
    stats = dict(b.stats, averaged_traces=a.stats.get("averaged_traces", 1) + b.stats.get("averaged_traces", 1))
    stats["averaged_entries"] = int(entries[0].numel())
    linear = None if a.linear is None else ((a.linear + b.linear) * 0.5).coalesce()
    noisy = [x.irradiance - (0 if x.exact_irradiance is None else x.exact_irradiance) for x in (a, b)]
    exact = 0 if b.exact_irradiance is None else b.exact_irradiance
    irradiance = 0.5 * (noisy[0] + noisy[1]) + exact
    return PhotonCache(a.brdf, irradiance, *entries, weight, stats, linear, b.smoother, b.exact_irradiance)
