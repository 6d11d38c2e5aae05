"""Building the photon cache (torchrefl.transport.photon_cache: what it holds) from photon hits
(torchrefl.transport.photon_trace).

Density estimation (the kernels are in torchrefl.transport.photon_density). A texel's H from its own
photons is noisy (a few photons per light and texel); with `smoothing` > 0 (texels) H is smoothed over
neighbouring texels on the surface (the Surface's neighbours) with Gaussian weights
(std `smoothing`): the photon-map gather radius, trading noise for blur where the indirect light changes
fast. With `smoothing_normal` s > 0 a neighbour also weighs exp(-|n - n'|^2 / (2 s^2)) by how far its
normal n' is from the texel's n (a joint bilateral filter guided by the normals, as kornia's
joint_bilateral_blur), so the kernel gathers along the surface and not across a fold or a crease, where
the two sides receive different indirect light (a photon map's gather with a normal test). The smoothing
is local linear (smoothing_matrix, a sparse operator built once): each texel takes the value of the plane
fitted with these weights through its neighbours, which inside a region is the normalised Gaussian (tested
equal to kornia's there) and next to a fold or an edge, where the neighbours lie on one side, keeps the rise
of the light towards the fold that the normalised kernel flattens. The
specular entries stay per texel unless `specular_smoothing` > 0 spreads each photon's entry over
its surface neighbours with the same kind of kernel (spread_on_grid): per-texel entries come from a few
photons each, and that noise, multiplying Ps in the fit, biases Ps down (errors in variables). Where the
all-diffuse paths come from the radiosity level, torchrefl.transport.specular_gather replaces their
specular entries by gathered ones without photon noise (build_cache(specular_paths_only=True) then keeps
only the photons whose path had a specular scattering).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import torch

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.lobe_sampling import column_dot
from torchrefl.core.threads import thread_map
from torchrefl.errors import ConfigError
from torchrefl.transport.light_maps import LightSources
from torchrefl.transport.photon_cache import PhotonCache
from torchrefl.transport.photon_density import SpreadKernel, apply_on_grid, smoothing_matrix
from torchrefl.transport.photon_hits import PhotonHits, shared_hits
from torchrefl.transport.specular_bins import BIN_PER_SIGMA, THETA_BIN, light_slices, spread_and_merge

LOBE_CUTOFF = 1e-7


class _Receivers(NamedTuple):
    """build_cache's description of the receiving texels and observations (its docstring)."""

    areas: object
    normals: object
    view_dirs: object
    keep: object
    brdf: str
    sigma: object
    sigma_max: float
    min_cos_light: float


@dataclass(frozen=True)
class _Options:
    """build_cache's options that each light's reduction takes as they are (its docstring)."""

    theta_bin: float
    bin_per_sigma: float
    threads: int
    smoother: torch.Tensor | None
    grid: tuple | None
    smoothing_normal: float
    specular_smoothing: float
    diffuse_paths: bool
    specular_paths_only: bool
    spreader: SpreadKernel | None


def _grid_parts(grid: tuple) -> tuple:
    """(neighbours, normals or None) of a grid tuple (neighbours[, normals]): the Surface's neighbours
    (core/texel_neighbours.py) and its texel normals (T, 3)."""
    return grid[0], (grid[1] if len(grid) > 1 else None)


def build_cache(
    hits: PhotonHits,
    sources: LightSources,
    areas,
    normals,
    view_dirs,
    keep,
    brdf: str,
    sigma,
    sigma_max: float,
    min_cos_light: float,
    dtype=torch.float64,
    theta_bin: float = THETA_BIN,
    bin_per_sigma: float = BIN_PER_SIGMA,
    threads: int = 2,
    smoother: torch.Tensor | None = None,
    smoothing: float = 0.0,
    grid=None,
    emitter_pd=None,
    smoothing_normal: float = 0.0,
    specular_smoothing: float = 0.0,
    diffuse_paths: bool = True,
    specular_paths_only: bool = False,
    spreader: SpreadKernel | None = None,
    image_light: np.ndarray | None = None,
) -> PhotonCache:
    """Reduce photon hits to the cache.

    hits: from PhotonTracer.trace over sources.positions.reshape(-1, 3) (source s = p * K + k);
    areas (T,), normals (T, 3), view_dirs (T, 3) or (P, T, 3); keep (P, T) bool observations that are
    predicted (fitted or evaluated); sigma (T,) current roughness (prunes the specular entries);
    smoothing: std of the Gaussian density-estimation kernel in texels (needs grid = (neighbours,) or
    (neighbours, normals (T, 3)), neighbours the Surface's); smoothing_normal: the kernel's normal-difference std (needs
    the normals in grid; 0 = plain Gaussian); specular_smoothing: std (texels) of the kernel that spreads the
    specular entries over surface neighbours (spread_on_grid; 0 = per texel); theta_bin, bin_per_sigma: merged
    photons' theta_h bins are max(theta_bin, bin_per_sigma * sigma_t) wide; threads: worker threads;
    smoother: smoothing_matrix(neighbours, smoothing, normals, smoothing_normal) built by the caller
    once for many caches (built here when None); spreader: the specular spread's SpreadKernel(neighbours,
    specular_smoothing, normals, smoothing_normal), likewise;
    emitter_pd (T, 3): the Pd the photons were traced with; with it (and hits.emitter) H is linear in Pd;
    diffuse_paths: False leaves the photons whose paths were diffuse at every scattering (hits.specular_path
    False) out of H, for a caller that adds those paths' irradiance from the radiosity level (their
    expectation); the specular entries keep every photon unless specular_paths_only (for a caller that gathers
    the receiving texel's specular reflection of the all-diffuse paths' light itself: specular_gather).

    Without emitter_pd the hits are reduced one light at a time (the same cache, bit for bit: a light's hits feed
    only its own observations and its own specular entries, in the same order), so the reduction's temporaries
    are one light's.

    image_light (P,): where images share lights (distinct_lights), the hits are the distinct lights' (source
    u * K + k) and image p takes light image_light[p]'s: a light's hits are reduced once for the irradiance of all its
    images (it does not depend on the camera) and once per image for the specular entries, and held once, not once
    per image (the same cache as shared_hits' copies).
    """
    receivers = _Receivers(areas, normals, view_dirs, keep, brdf, sigma, sigma_max, min_cos_light)
    options = _Options(
        theta_bin=theta_bin,
        bin_per_sigma=bin_per_sigma,
        threads=threads,
        smoother=smoother,
        grid=grid,
        smoothing_normal=smoothing_normal,
        specular_smoothing=specular_smoothing,
        diffuse_paths=diffuse_paths,
        specular_paths_only=specular_paths_only,
        spreader=spreader,
    )
    K = sources.positions.shape[1]
    if image_light is not None and emitter_pd is not None:  # the part linear in Pd is built from all hits at once
        hits, image_light = shared_hits(hits, np.asarray(image_light), K), None
    if emitter_pd is None and (image_light is not None or _several_lights(hits, sources)):
        return _build_by_light(hits, sources, receivers, options, dtype, smoothing, image_light)
    return _build_at_once(hits, sources, receivers, options, dtype, smoothing, emitter_pd)


def _several_lights(hits: PhotonHits, sources: LightSources) -> bool:
    """Whether the hits come from more than one light (source s = p * K + k)."""
    if not hits.count:
        return False
    light = hits.source // sources.positions.shape[1]
    return int(light.min()) != int(light.max())


def _build_at_once(
    hits: PhotonHits,
    sources: LightSources,
    receivers: _Receivers,
    options: _Options,
    dtype,
    smoothing: float,
    emitter_pd,
) -> PhotonCache:
    """build_cache of all the hits in one reduction (emitter_pd: with it the part linear in Pd)."""
    P, K = sources.positions.shape[:2]
    T = int(receivers.areas.shape[0])
    scale, flux, obs_idx = _photon_flux(hits, sources, receivers.areas, T)
    H, in_H = _photon_irradiance(hits, flux, obs_idx, P * T, options.diffuse_paths, options.specular_paths_only)
    linear = None
    if emitter_pd is not None and hits.emitter is not None and hits.count:
        linear = _linear_in_pd(H, hits, scale, in_H, obs_idx, emitter_pd, P, T, dtype)
    stats = _hit_stats(hits, K)
    entries, spread_photons = _cache_entries(hits, flux, obs_idx, receivers, options, T, dtype)
    if spread_photons is not None:
        stats["specular_photons"] = spread_photons
    stats["specular_entries"] = int(entries[0].numel())
    irradiance = torch.from_numpy(H.reshape(P, T, 3))
    smoother = options.smoother
    if smoothing > 0:
        irradiance, smoother = _smooth_irradiance(
            irradiance, options.grid, smoother, smoothing, options.smoothing_normal
        )
    if linear is not None:
        stats["linear_entries"] = int(linear._nnz())
    # the smoother serves the part linear in Pd only (irradiance_at): a cache without one does not keep it (a copy
    # per cache in the cache's dtype, PhotonCache.to, 0.4 GB on the fold)
    keep_smoother = smoothing > 0 and linear is not None
    return PhotonCache(
        receivers.brdf,
        irradiance.to(dtype),
        *entries,
        stats=stats,
        linear=linear,
        smoother=smoother if keep_smoother else None,
    )


def _hit_stats(hits: PhotonHits, K: int) -> dict:
    """The cache's counts of its trace: hits stored, rays traced, back-side hits, photons emitted, maps per light."""
    stats = {"stored_hits": hits.count, "rays": hits.rays, "back_side_hits": int(hits.back_hits)}
    stats.update(photons_emitted=int(hits.emitted.sum()), maps_per_light=K)
    return stats


def _cache_entries(hits: PhotonHits, flux, obs_idx, receivers: _Receivers, options: _Options, T: int, dtype):
    """(the cache's specular entries (obs (E,), theta_h (E,), weight (E, 3)): the hits' lobe entries merged in theta_h
    bins and, with options.specular_smoothing, spread over surface neighbours; the number of photons spread_and_merge
    counted, or None where no hit got an entry)."""
    _, normals, view_dirs, keep, brdf, sigma, sigma_max, min_cos_light = receivers
    empty = (torch.zeros(0, dtype=torch.long), torch.zeros(0, dtype=dtype), torch.zeros(0, 3, dtype=dtype))
    sel = _lobe_hits(hits, keep, obs_idx, brdf != "lambertian", options.specular_paths_only)
    if not sel.size:
        return empty, None
    e_obs, theta_h, weight = _SpecularEntries(
        hits, obs_idx, normals, view_dirs, brdf, sigma, sigma_max, min_cos_light, options.threads
    ).select(sel, flux)
    spread = _entry_spread(options, T)
    if not e_obs.size:
        return empty, None
    merged, count = spread_and_merge(e_obs, theta_h, weight, spread, sigma, T, options.theta_bin, options.bin_per_sigma)
    return (torch.from_numpy(merged[0]), *(torch.from_numpy(x).to(dtype) for x in merged[1:])), count


def _entry_spread(options: _Options, T: int):
    """spread_and_merge's spread of the specular entries over their surface neighbours (options.specular_smoothing,
    with options.spreader or one built here), or None without specular smoothing."""
    if options.specular_smoothing > 0 and options.grid is None:
        raise ConfigError("photon.specular_smoothing > 0 needs the texel neighbours (grid = (neighbours,))")
    if not options.specular_smoothing > 0:
        return None
    spreader = _spread_kernel(options) if options.spreader is None else options.spreader
    return lambda obs: spreader(obs, T)


def _spread_kernel(options: _Options) -> SpreadKernel:
    """The SpreadKernel of options.specular_smoothing over options.grid's neighbours (and normals)."""
    nbrs, gnormals = _grid_parts(options.grid)
    return SpreadKernel(nbrs, options.specular_smoothing, gnormals, options.smoothing_normal)


def _build_by_light(
    hits: PhotonHits,
    sources: LightSources,
    receivers: _Receivers,
    options: _Options,
    dtype,
    smoothing: float,
    image_light: np.ndarray | None = None,
) -> PhotonCache:
    """build_cache one light at a time (no part linear in Pd): each light's hits reduced alone in float64 and
    unsmoothed, `threads` lights at once (one thread each: a light's reduction is mostly single-threaded numpy), its
    irradiance written to its images' rows and smoothed once, their specular entries concatenated in image order
    (spread_and_merge's order). With image_light (build_cache) a light's irradiance is reduced once for all its
    images (it does not depend on the view) and its specular entries once per image."""
    P, K = sources.positions.shape[:2]
    T = int(receivers.areas.shape[0])
    if options.specular_smoothing > 0 and options.spreader is None and options.grid is not None:
        options = replace(options, spreader=_spread_kernel(options))  # built once for all the lights
    if image_light is None:
        lights = [(idx, [p]) for p, idx in enumerate(light_slices(hits.source, K, P)) if idx.size]
    else:
        image_light = np.asarray(image_light)
        by_light = light_slices(hits.source, K, int(image_light.max()) + 1 if image_light.size else 0)
        lights = [(idx, np.flatnonzero(image_light == u).tolist()) for u, idx in enumerate(by_light) if idx.size]
    one, n = replace(options, threads=1), max(1, options.threads)
    reduce = lambda item: _reduce_light(hits.take(item[0]), item[1], sources, receivers, one, T)  # noqa: E731
    per_light = torch.zeros(len(lights), T, 3, dtype=torch.float64)  # a light's irradiance, the same in its images
    entries, spread = {}, []
    for start in range(0, len(lights), n):  # `threads` lights' temporaries alive at a time
        done = thread_map(reduce, lights[start : start + n], n)
        for j, ((_, images), (H, parts, count)) in enumerate(zip(lights[start : start + n], done), start):
            per_light[j] = torch.from_numpy(H)
            entries.update(zip(images, parts))
            spread += count
    if smoothing > 0:  # linear and per column: smoothed once per light, not per image
        per_light, _ = _smooth_irradiance(
            per_light, options.grid, options.smoother, smoothing, options.smoothing_normal
        )
    irradiance = torch.zeros(P, T, 3, dtype=torch.float64)
    for j, (_, images) in enumerate(lights):
        irradiance[images] = per_light[j]
    ordered = [entries[p] for p in sorted(entries)]
    empty = (
        torch.zeros(0, dtype=torch.long),
        torch.zeros(0, dtype=torch.float64),
        torch.zeros(0, 3, dtype=torch.float64),
    )
    obs, theta, weight = (torch.cat([e[i] for e in ordered] or [empty[i]]) for i in range(3))
    stats = _hit_stats(hits, K)  # the hits traced (with image_light, the distinct lights'), not their copies
    if spread:
        stats["specular_photons"] = sum(spread)
    stats["specular_entries"] = int(obs.numel())
    return PhotonCache(receivers.brdf, irradiance.to(dtype), obs, theta.to(dtype), weight.to(dtype), stats=stats)


def _reduce_light(hits: PhotonHits, images: list, sources: LightSources, receivers: _Receivers, options: _Options, T):
    """One light's hits reduced for each of its images (their source's map k = source % K; the image is not read from
    the source): (H (T, 3) float64 the light's irradiance per texel, each image's specular entries (obs, theta_h,
    weight) in float64, the photons spread_and_merge counted per image that has entries)."""
    _, flux, _ = _photon_flux(hits, sources, receivers.areas, T)
    t = np.asarray(hits.texel)
    H, _ = _photon_irradiance(hits, flux, t, T, options.diffuse_paths, options.specular_paths_only)
    parts, counts = [], []
    for p in images:
        entries, count = _cache_entries(hits, flux, p * T + t, receivers, options, T, torch.float64)
        parts.append(entries)
        if count is not None:
            counts.append(count)
    return H, parts, counts


def _lobe_hits(hits: PhotonHits, keep, obs_idx, lobe: bool, specular_paths_only: bool) -> np.ndarray:
    """Indices of the hits that get specular entries: at kept observations, with a lobe, and (specular_paths_only)
    only those whose path had a specular scattering."""
    keep_np = np.asarray(keep, dtype=bool).reshape(-1)
    wanted = np.take(keep_np, obs_idx)
    if specular_paths_only and lobe:
        wanted &= np.asarray(hits.specular_path, dtype=bool)
    return np.flatnonzero(wanted) if lobe else np.zeros(0, dtype=np.int64)


def _photon_flux(hits: PhotonHits, sources: LightSources, areas, T: int):
    """(scale (N,): each photon's light-map weight at its texel over the texel area, flux (3, N) per unit
    collection area, component-major, obs_idx (N,): flat observation p * T + t of each photon)."""
    K = sources.positions.shape[1]
    A = np.asarray(areas, dtype=np.float64)
    p = hits.source // K
    t = hits.texel
    # photons' flux per unit collection area, with the light-map weight of their texel, component-major (3, N)
    # (np.take and row-vector products: several times faster than fancy indexing and (N, 3) broadcasts)
    scale = np.take(np.asarray(sources.weights, dtype=np.float64).reshape(-1), (hits.source % K) * T + t) / np.take(
        A, t
    )
    if hits.density_weight is not None:  # irradiance on the texel's normal, not the hit face's (photon_trace)
        scale = scale * np.asarray(hits.density_weight, dtype=np.float64)
    flux = np.asarray(hits.power, dtype=np.float64).T * scale  # (3, N)
    obs_idx = p * T + t
    return scale, flux, obs_idx


def _photon_irradiance(hits: PhotonHits, flux, obs_idx, PT: int, diffuse_paths: bool, specular_paths_only: bool):
    """(H (P T, 3): the photons' irradiance per observation, in_H (N,) float64 1 where a photon counts in H, or
    None when all do)."""
    if (not diffuse_paths or specular_paths_only) and hits.specular_path is None:
        raise ValueError(
            "build_cache: diffuse_paths=False or specular_paths_only needs hits.specular_path "
            "(PhotonTracer.trace records it)"
        )
    in_H = None if diffuse_paths else np.asarray(hits.specular_path, dtype=np.float64)  # (N,) 1 = counted in H
    # one channel at a time: no (3, N) copy of the flux beside it
    H = np.stack(
        [np.bincount(obs_idx, weights=flux[c] if in_H is None else flux[c] * in_H, minlength=PT) for c in range(3)], -1
    )
    return H, in_H


def _linear_in_pd(H, hits: PhotonHits, scale, in_H, obs_idx, emitter_pd, P: int, T: int, dtype) -> torch.Tensor:
    """The sparse (3 P T, 3 T) L of PhotonCache.linear; subtracts its part at emitter_pd from H (P T, 3) in place."""
    lin = np.asarray(hits.diffuse_per_pd, dtype=np.float64).T * (scale if in_H is None else scale * in_H)  # per unit Pd
    e = hits.emitter
    pd_ref = np.asarray(emitter_pd, dtype=np.float64)
    for c in range(3):
        H[:, c] -= np.bincount(obs_idx, weights=lin[c] * np.take(pd_ref[:, c], e), minlength=P * T)
    rows = np.concatenate([c * P * T + obs_idx for c in range(3)])
    cols = np.concatenate([c * T + e for c in range(3)])
    return (
        torch.sparse_coo_tensor(
            torch.from_numpy(np.stack([rows, cols])),
            torch.from_numpy(lin.reshape(-1)),
            (3 * P * T, 3 * T),
            check_invariants=False,
        )
        .coalesce()
        .to(dtype)
    )


class _SpecularEntries:
    """The specular entries of selected photon hits: their theta_h and weight, pruned where the lobe at the
    receiving texel's capped roughness is negligible (build_cache)."""

    def __init__(self, hits, obs_idx, normals, view_dirs, brdf, sigma, sigma_max, min_cos_light, threads):
        self.t = hits.texel
        self.obs_idx = obs_idx
        self.normals_3 = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).T)
        v_all = np.asarray(view_dirs, dtype=np.float64)
        self.v_3, self.per_light_view = np.ascontiguousarray(v_all.reshape(-1, 3).T), v_all.ndim == 3
        self.sigma_cap = np.minimum(3.0 * np.asarray(sigma, dtype=np.float64), sigma_max)
        self.wi_3 = np.asarray(hits.direction).T
        self.brdf = brdf
        self.min_cos_light = min_cos_light
        self.threads = threads

    def select(self, sel: np.ndarray, flux: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(flat observation (M,), theta_h (M,), weight (3, M)) of the alive hits among sel."""
        # blocks of 2^17 hits keep the temporaries in cache; numpy releases the GIL, so two threads share them
        blocks = [sel[i : i + (1 << 17)] for i in range(0, sel.size, 1 << 17)]
        parts = thread_map(self.block, blocks, self.threads)
        sel = np.concatenate([x[0] for x in parts])
        theta_h = np.concatenate([x[1] for x in parts])
        weight = np.take(flux, sel, axis=1) * np.concatenate([x[2] for x in parts])  # (3, M)
        return np.take(self.obs_idx, sel), theta_h, weight

    def block(self, sb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(alive selected hits, their theta_h, G / cos_i) for a block of selected hits (cache-sized)."""
        tt = torch.from_numpy
        brdf, min_cos_light = self.brdf, self.min_cos_light
        ts = np.take(self.t, sb)
        n = np.take(self.normals_3, ts, axis=1)  # (3, M)
        v = np.take(self.v_3, np.take(self.obs_idx, sb) if self.per_light_view else ts, axis=1)
        wi = np.take(self.wi_3, sb, axis=1).astype(np.float64)
        cos_i, cos_v = column_dot(n, wi), column_dot(n, v)
        with torch.no_grad():
            th = brdf_mod.half_angle(tt(n.T), tt(wi.T), tt(v.T)).numpy()  # (M, 3) views of the (3, M) arrays
            geom = (brdf_mod.specular_geometry(brdf, tt(cos_i), tt(cos_v)) / tt(cos_i).clamp_min(min_cos_light)).numpy()
            lobe_at = brdf_mod.specular_lobe(brdf, tt(th), tt(np.take(self.sigma_cap, ts))).numpy()
        alive = np.flatnonzero((cos_i > min_cos_light) & (cos_v > 0) & (lobe_at > LOBE_CUTOFF))
        return np.take(sb, alive), np.take(th, alive), np.take(geom, alive)


def _smooth_irradiance(irradiance: torch.Tensor, grid, smoother, smoothing: float, smoothing_normal: float):
    """build_cache's density estimation: (irradiance smoothed over the grid, the smoother it used, built here
    when None)."""
    if grid is None:
        raise ConfigError("photon.smoothing > 0 needs the texel neighbours (grid = (neighbours,))")
    if smoothing_normal > 0 and _grid_parts(grid)[1] is None:
        raise ConfigError("photon.smoothing_normal > 0 needs the texel normals in the grid (neighbours, normals)")
    nbrs, normals = _grid_parts(grid)
    if smoother is None:
        smoother = smoothing_matrix(
            nbrs,
            smoothing,
            None if normals is None else np.asarray(normals, dtype=np.float64),
            smoothing_normal,
        )
    return apply_on_grid(smoother, irradiance), smoother
