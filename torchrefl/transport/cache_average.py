"""Two photon traces' caches as one: the photon level's refreshes from the third on fit the mean of the new trace
and the previous one (half the photon noise, no extra tracing; torchrefl.transport.levels.photon)."""

from __future__ import annotations

import numpy as np
import torch

from torchrefl.transport.photon_cache import PhotonCache
from torchrefl.transport.specular_bins import BIN_PER_SIGMA, THETA_BIN, light_slices, merge_entries


def average_caches(
    a: PhotonCache, b: PhotonCache, sigma, theta_bin: float = THETA_BIN, bin_per_sigma: float = BIN_PER_SIGMA
) -> PhotonCache:
    """The cache of two independent traces' photons at half weight each: the mean of their photon irradiance and of
    their parts linear in Pd (the part without photon noise, exact_irradiance, is b's: the newer), and both traces'
    specular entries merged again into the theta_h bins of roughness sigma (T,) (specular_bins.merge_entries), so
    the entries do not double. Both caches must share the smoother. The stats are
    b's (the newer trace's) with `averaged_traces` and `averaged_entries` (the merged entries) added. The entries are
    merged one light at a time (the same entries as one merge of all, with one light's temporaries alive)."""
    if (a.linear is None) != (b.linear is None):
        raise ValueError("average_caches: one cache is linear in the emitters' Pd and the other is not")
    entries = _merged_entries(a, b, np.asarray(sigma, dtype=np.float64), theta_bin, bin_per_sigma)
    stats = dict(b.stats, averaged_traces=a.stats.get("averaged_traces", 1) + b.stats.get("averaged_traces", 1))
    stats["averaged_entries"] = int(entries[0].numel())
    linear = None if a.linear is None else ((a.linear + b.linear) * 0.5).coalesce()
    noisy = [x.irradiance - (0 if x.exact_irradiance is None else x.exact_irradiance) for x in (a, b)]
    exact = 0 if b.exact_irradiance is None else b.exact_irradiance
    irradiance = 0.5 * (noisy[0] + noisy[1]) + exact
    return PhotonCache(a.brdf, irradiance, *entries, stats, linear, b.smoother, b.exact_irradiance)


def _merged_entries(a: PhotonCache, b: PhotonCache, sigma: np.ndarray, theta_bin: float, bin_per_sigma: float):
    """(entry_obs, entry_theta_h, entry_weight) of a's and b's specular entries at half weight merged into the theta_h
    bins, one light at a time: each light's entries, a's then b's in their order, are the rows that merge_entries of
    all entries at once sums for that light's observations, in the same order (the same sums, bit for bit)."""
    dt, dev = b.entry_weight.dtype, b.entry_weight.device
    P, T = a.irradiance.shape[:2]
    caches = [(x.entry_obs.cpu(), x.entry_theta_h.cpu(), x.entry_weight.cpu()) for x in (a, b)]
    slices = [light_slices(c[0].numpy(), T, P) for c in caches]
    parts = []
    for p in range(P):
        pick = [[x.index_select(0, torch.from_numpy(s[p])) for x in c] for c, s in zip(caches, slices)]
        obs = torch.cat([q[0] for q in pick]).numpy()
        if not obs.size:
            continue
        theta = torch.cat([q[1] for q in pick]).double().numpy()
        weight = (0.5 * torch.cat([q[2] for q in pick])).double().numpy().T
        parts.append(merge_entries(obs, theta, weight, sigma, T, theta_bin, bin_per_sigma))
    if not parts:
        return caches[0][0][:0].to(dev), caches[0][1][:0].to(dev, dt), caches[0][2][:0].to(dev, dt)
    obs, theta, weight = (np.concatenate([part[i] for part in parts]) for i in range(3))
    return torch.from_numpy(obs).to(dev), torch.from_numpy(theta).to(dev, dt), torch.from_numpy(weight).to(dev, dt)
