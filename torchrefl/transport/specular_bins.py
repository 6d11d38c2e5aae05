"""The theta_h bins of the photon cache's specular entries, and the merge of the entries that share one.

An entry (observation p T + t, theta_h, weight) stands for light that texel t reflects towards the camera in light
p's image with Ps_t D(theta_h; sigma_t) times the weight. Entries of one observation whose theta_h differ by a
fraction of the lobe's width can be summed into one at their weighted mean theta_h: sum_k w_k D(theta_k) changes
by < 0.5 % (second order in the spread within a bin), and D stays differentiable in sigma. Used by the photons'
entries (cache_build.build_cache) and the gathered ones (specular_gather).
"""

from __future__ import annotations

import math

import numpy as np
import torch

THETA_BIN = 0.004  # radians; merged photons differ in theta_h by less than this, or by
BIN_PER_SIGMA = 0.25  # less than this fraction of the receiving texel's current roughness where that is wider
#: bins per texel and observation: theta_h in [0, pi / 2] in bins at least THETA_BIN wide
BINS_PER_OBSERVATION = int(math.pi / 2 / THETA_BIN) + 2


def theta_bins(theta_h, sigma_t, theta_bin: float = THETA_BIN, bin_per_sigma: float = BIN_PER_SIGMA) -> np.ndarray:
    """(M,) int64 bin of each entry's theta_h (M,) at its receiving texel's roughness sigma_t (M,): bins
    max(theta_bin, bin_per_sigma * sigma_t) wide."""
    width = np.maximum(theta_bin, bin_per_sigma * np.asarray(sigma_t, dtype=np.float64))
    return np.floor(np.asarray(theta_h) / width).astype(np.int64)


def merge_entries(
    e_obs: np.ndarray,
    theta_h: np.ndarray,
    weight: np.ndarray,
    sigma,
    T: int,
    theta_bin: float = THETA_BIN,
    bin_per_sigma: float = BIN_PER_SIGMA,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge specular entries (flat observation e_obs = p T + t (M,), theta_h (M,), weight (3, M)) whose theta_h fall
    in the same bin of the same observation: bins max(theta_bin, bin_per_sigma * sigma_t) wide for the texel's
    roughness sigma (T,); merging entries whose theta_h differ by a fraction of the lobe's width changes
    sum_k w_k D(theta_k) by < 0.5 % (second order in the spread within a bin). Returns (entry_obs (E,), the
    weight-averaged theta_h (E,), summed weight (E, 3)), sorted by observation and bin."""
    # theta_bins with the bin widths taken per texel (the same values, a pass fewer over the entries)
    width = np.maximum(theta_bin, bin_per_sigma * np.asarray(sigma, dtype=np.float64))
    bins = np.floor(np.asarray(theta_h) / np.take(width, _texel_of(e_obs, T))).astype(np.int64)
    inv = sorted_inverse(e_obs, bins)  # each entry's merged entry, in the order of (observation, bin)
    count = int(inv.max()) + 1 if inv.size else 0
    m = weight.mean(0)
    wsum = np.stack([np.bincount(inv, weights=weight[c], minlength=count) for c in range(3)], -1)
    msum = np.bincount(inv, weights=m, minlength=count)
    tsum = np.bincount(inv, weights=m * theta_h, minlength=count)
    first = np.zeros(count, dtype=np.int64)
    first[inv[::-1]] = np.arange(len(inv))[::-1]
    mean_theta = np.where(msum > 0, tsum / np.where(msum > 0, msum, 1.0), np.take(theta_h, first))
    return np.take(e_obs, first), mean_theta, wsum


#: sorted_inverse counts the (observation, bin) slots densely while they are at most this many per entry (5 bytes a
#: slot: no more memory than the sort's)
DENSE_SLOTS_PER_ENTRY = 4


#: sorted_inverse merges sorted runs (timsort) while there are at most one per this many keys, and sorts anew beyond
#: (5 M keys: 0.07 s for 2 runs, 0.79 s for 16 k runs, 0.84 s by torch.unique, 1.7 s by timsort in random order)
RUN_SORT_MAX_RUNS_PER_ENTRY = 256


def sorted_inverse(obs: np.ndarray, bins: np.ndarray) -> np.ndarray:
    """(M,) int64 the rank of each entry's (obs, bin) (M,) int64 among the distinct pairs in sorted order (obs, then
    bin). Counted over the dense slots of (obs - min obs, bin - min bin) where they are few (one light's entries:
    its texels x the bins in use), by a stable sort otherwise (the cache average's: two sorted runs, which timsort
    merges in linear time). (A merged entry's mean theta_h can leave [0, pi / 2] where
    its photons' weights have both signs: its bin is then negative or past the last, which the key
    obs * BINS_PER_OBSERVATION + bin once ran into the neighbouring observation's bins.)"""
    if not obs.size:
        return np.zeros(0, dtype=np.int64)
    lo, b0 = int(obs.min()), int(bins.min())
    nb = int(bins.max()) - b0 + 1
    slots = (int(obs.max()) - lo + 1) * nb
    if slots > DENSE_SLOTS_PER_ENTRY * obs.size + (1 << 16):
        new = np.empty(obs.size, dtype=bool)
        new[0] = False
        if slots < 2**62:
            key = (obs - lo) * nb + (bins - b0)
            if np.count_nonzero(key[1:] < key[:-1]) > obs.size // RUN_SORT_MAX_RUNS_PER_ENTRY:
                # many runs (a spread's copies): a full sort, torch's is about 2x numpy's
                return torch.unique(torch.from_numpy(key), sorted=True, return_inverse=True)[1].numpy()
            # a stable sort (timsort) merges the sorted runs of merged entries (the cache average's two) in linear time
            order = np.argsort(key, kind="stable")
            k = np.take(key, order)
            np.not_equal(k[1:], k[:-1], out=new[1:])
        else:  # keys past int64: sort the pairs
            order = np.lexsort((bins, obs))
            o, b = np.take(obs, order), np.take(bins, order)
            new[1:] = (o[1:] != o[:-1]) | (b[1:] != b[:-1])
        inv = np.empty(obs.size, dtype=np.int64)
        inv[order] = np.cumsum(new)
        return inv
    key = (obs - lo) * nb + (bins - b0)
    present = np.zeros(slots, dtype=bool)
    present[key] = True
    rank = np.cumsum(present, dtype=np.int32 if slots < 2**31 else np.int64)
    return np.take(rank, key).astype(np.int64) - 1


def _texel_of(obs: np.ndarray, T: int) -> np.ndarray:
    """(M,) the texel t of flat observations obs = p T + t (a subtraction where they are all one light's)."""
    if obs.size and int(obs.min()) // T == int(obs.max()) // T:
        return obs - (int(obs.min()) // T) * T
    return obs % T


def spread_and_merge(e_obs, theta_h, weight, spread, sigma, T: int, theta_bin: float, bin_per_sigma: float):
    """merge_entries of the specular entries after spread (obs -> (copies' obs, source entry, weight); None: no
    spread), one light at a time: a light's copies stay among its own observations, so the pieces are the global
    merge in its order, and the copies (a kernel's worth per entry) are never all held at once. Returns the merged
    (entry_obs, theta_h, weight) and the number of (spread) entries merged."""
    parts, count = [], 0
    for idx in light_slices(e_obs, T):
        if not idx.size:
            continue
        obs, th, w = np.take(e_obs, idx), np.take(theta_h, idx), np.take(weight, idx, axis=1)
        if spread is not None:
            obs, src, k = spread(obs)
            th, w = np.take(th, src), np.take(w, src, axis=1) * k
        count += int(obs.size)
        parts.append(merge_entries(obs, th, w, sigma, T, theta_bin, bin_per_sigma))
    return tuple(np.concatenate([part[i] for part in parts]) for i in range(3)), count


def light_slices(e_obs: np.ndarray, T: int, lights: int | None = None) -> list[np.ndarray]:
    """The indices of the entries (flat observations e_obs = p T + t (M,)) of each light p = 0 .. lights - 1 (default:
    up to the largest present; lights must not be fewer), each in the entries' order (a stable sort): the pieces of
    a merge one light at a time, since merge_entries never merges entries of different lights."""
    light = np.asarray(e_obs) // T
    n = lights if lights is not None else (int(light.max()) + 1 if light.size else 0)
    order = np.argsort(light, kind="stable")
    ends = np.searchsorted(np.take(light, order), np.arange(n), side="right")
    return [order[begin:end] for begin, end in zip([0, *ends[:-1].tolist()], ends.tolist())]
