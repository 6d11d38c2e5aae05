"""Prediction at the photon level (Method III): local direct light plus the cached indirect light.

The cache holds, for every light p and texel t, what the photons stored there (second and later
bounces, torchrefl.transport.photon_trace) bring:
    H_pt   = sum_k Phi_k w_k u_k / A_t                          indirect irradiance (P, T, 3)
    entries (p, t, theta_h, c): the photons' incident directions reduced to what the specular lobe
           needs: theta_h = angle(n_t, half(wi_k, v_pt)) and c = Phi_k w_k / A_t * G(cos_i, cos_v) / cos_i,
           merged over photons of the same (p, t) whose theta_h falls in the same bin (power-weighted
           mean theta_h; bins max(0.004 rad, sigma_t / 4) wide for the texel's current roughness sigma_t:
           within 1 % of the unmerged sum, 3 % if the fit halves sigma before the next refresh), kept only
           for fitted or evaluated observations and where the lobe at the texel's current roughness
           (times 3, capped at sigma_max) is above 1e-7.
w_k are the light-position weights below, u_k the hit's density weight (PhotonHits.density_weight: irradiance on the
texel's normal; Phi_k below stands for Phi_k u_k). H is kept linear in the Pd of the texel each photon was
last scattered from (its emitter e_k): the part of Phi_k that the emitter's diffuse reflection
carries is exactly proportional to Pd_e at that bounce, so
    H_pt(Pd) = H0_pt + sum_k L_k Pd_{e_k},   L_k = Phi_k^diffuse-per-unit-Pd w_k / A_t
(a sparse (light, texel) x texel matrix per channel), which makes the last bounce exact and
differentiable in the emitters' Pd between refreshes; earlier bounces stay as traced. The reflected
indirect light is differentiable in the receiving texel's parameters and in the emitters' Pd:
    i_ind(p, t) = kappa * ( Pd_t / pi * H_pt(Pd) + Ps_t * sum_entries D(theta_h; sigma_t) c )
the photon estimate of kappa * sum_k f_t(wi_k, v_pt) Phi_k / A_t with f = g / cos_i (torchrefl.core.brdf).
Photons reaching the texel at n.wi <= min_cos_light feed H but not the specular sum (the fitter
does not use grazing light either).

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

Moving lights. On the cylindrical rig the lights co-rotate with the scan, so each texel column sees
light p from its own position L_pt = x_t + l_pt / sqrt(falloff_pt). `light_sources` places K
sources per light at evenly spaced columns; a texel's indirect light interpolates the maps in its column
(`map_weights`: cubic Lagrange through the four nearest sources; the tent between the two nearest left the
indirect light of Object E's lower plate 1.3 % low at 8 maps, since it bends with the light's position, and
the end columns beyond the outer sources took the end maps' values unchanged). A capture whose lights do
not move uses one source per light.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.lobe_sampling import column_dot
from torchrefl.core.threads import thread_map
from torchrefl.errors import ConfigError
from torchrefl.transport.photon_density import SpreadKernel, apply_on_grid, smoothing_matrix
from torchrefl.transport.photon_hits import PhotonHits
from torchrefl.transport.specular_bins import BIN_PER_SIGMA, THETA_BIN, light_slices, spread_and_merge
from torchrefl.transport.texel_model import SpecularEntries

LOBE_CUTOFF = 1e-7


@dataclass
class LightSources:
    """positions (P, K, 3) source positions of light p's K maps; weights (K, T) per-texel weights of
    the maps (each column sums to 1); intensity (P, 3)."""

    positions: np.ndarray
    weights: np.ndarray
    intensity: np.ndarray

    @property
    def num_maps(self) -> int:
        return int(self.positions.shape[1])


def texel_light_positions(surface, obs) -> np.ndarray:
    """(P, T, 3) position of light p as texel t saw it: x_t + l_pt / sqrt(falloff_pt)."""
    if obs.light_positions is None:
        raise ConfigError(
            f"fit.model: 'photon' needs point lights, but the capture {obs.source} has directional "
            "lights: use fit.model=local"
        )
    dist = 1.0 / torch.sqrt(obs.falloff.double().clamp_min(1e-300))
    return (surface.positions.double()[None] + obs.light_dir.double() * dist[..., None]).numpy()


def map_weights(s: np.ndarray, K: int, order: int = 3) -> np.ndarray:
    """(K, T) weights of K maps at map coordinates 0..K-1 for texels at map coordinate s (T,): Lagrange
    interpolation through the order + 1 nearest maps (fewer when K is smaller; order 1 = the tent between
    the two nearest; past the end maps the same polynomial extrapolates). Every column sums to 1 and a field
    that is a polynomial of that order in s is reproduced exactly; order 3 weights dip below 0 between
    maps (to -0.064 in the middle intervals, -0.32 in the two end ones), and their root sum of squares, the
    gain on independent noise in the maps, stays below 1.09 between the end maps."""
    s = np.asarray(s, dtype=np.float64)
    T = s.shape[0]
    if K <= 1:
        return np.ones((1, T))
    n = min(order + 1, K)
    j0 = np.clip(np.floor(s).astype(np.int64) - (n - 1) // 2, 0, K - n)
    weights = np.zeros((K, T))
    for a in range(n):
        w = np.ones(T)
        for b in range(n):
            if b != a:
                w *= (s - (j0 + b)) / (a - b)
        weights[j0 + a, np.arange(T)] += w
    return weights


def light_sources(surface, obs, max_maps: int, order: int = 3) -> LightSources:
    """Sources and their per-texel map weights (module docstring; map_weights of this order); one map per
    light when no light moves."""
    L = texel_light_positions(surface, obs)
    P, T, _ = L.shape
    intensity = obs.light_intensity.double().numpy()
    centre = np.median(L, axis=1)  # (P, 3)
    spread = float(np.abs(L - centre[:, None]).max()) if T else 0.0
    scale = float(np.abs(surface.positions.double().numpy()).max()) + 1.0
    if spread <= 1e-6 * scale or max_maps <= 1:
        return LightSources(
            centre[:, None] if spread <= 1e-6 * scale else L.mean(1)[:, None], np.ones((1, T)), intensity
        )
    W = surface.grid_shape[1]
    col = (surface.texel_index.numpy() % W).astype(np.float64)
    cmin, cmax = col.min(), col.max()
    K = int(min(max_maps, cmax - cmin + 1))
    if K == 1:
        return LightSources(L.mean(1)[:, None], np.ones((1, T)), intensity)
    # the outer maps sit on the outermost columns, so every texel interpolates (no extrapolation, whose
    # weights would amplify a photon map's noise at the object's ends)
    step = (cmax - cmin) / (K - 1)
    centres = cmin + step * np.arange(K)
    weights = map_weights((col - cmin) / step, K, order)
    positions = np.empty((P, K, 3))
    for k, c in enumerate(centres):
        nearest = np.abs(col - c)
        sel = nearest <= nearest.min() + 1e-9
        positions[:, k] = L[:, sel].mean(1)
    return LightSources(positions, weights, intensity)


@dataclass
class PhotonCache:
    """irradiance (P, T, 3) H0 (smoothed); entry_obs (E,) flat p*T + t; entry_theta_h (E,); entry_weight (E, 3);
    linear: sparse (3 P T, 3 T) L, rows c P T + p T + t, columns c T + e, or None; smoother: the
    density-estimation kernel (smoothing_matrix) applied to L Pd, or None (H0 is stored smoothed; None without
    linear); exact_irradiance:
    the part of H0 without photon noise (the radiosity level's all-diffuse paths, photon.diffuse_paths: radiosity),
    or None."""

    brdf: str
    irradiance: torch.Tensor
    entry_obs: torch.Tensor
    entry_theta_h: torch.Tensor
    entry_weight: torch.Tensor
    stats: dict = field(default_factory=dict)
    linear: torch.Tensor | None = None
    smoother: torch.Tensor | None = None
    exact_irradiance: torch.Tensor | None = None

    def to(self, dtype: torch.dtype, device=None) -> "PhotonCache":
        mv = lambda x: x.to(device=device, dtype=dtype if x.is_floating_point() else x.dtype)
        return PhotonCache(
            self.brdf,
            mv(self.irradiance),
            mv(self.entry_obs),
            mv(self.entry_theta_h),
            mv(self.entry_weight),
            dict(self.stats),
            None if self.linear is None else mv(self.linear),
            None if self.smoother is None else mv(self.smoother),
            None if self.exact_irradiance is None else mv(self.exact_irradiance),
        )

    def irradiance_at(self, pd: torch.Tensor) -> torch.Tensor:
        """(P, T, 3) H(Pd) for texel Pd (T, 3)."""
        if self.linear is None:
            return self.irradiance
        P, T, _ = self.irradiance.shape
        lin = torch.sparse.mm(self.linear, pd.t().reshape(-1, 1).to(self.irradiance.dtype))
        lin = lin.reshape(3, P, T).permute(1, 2, 0)
        if self.smoother is not None:
            lin = apply_on_grid(self.smoother, lin)
        return self.irradiance + lin


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
    """
    if emitter_pd is None and _several_lights(hits, sources):
        return _build_by_light(
            hits,
            sources,
            (areas, normals, view_dirs, keep, brdf, sigma, sigma_max, min_cos_light),
            dict(
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
            ),
            dtype,
            smoothing,
        )
    P, K = sources.positions.shape[:2]
    T = int(areas.shape[0])
    scale, flux, obs_idx = _photon_flux(hits, sources, areas, T)
    H, in_H = _photon_irradiance(hits, flux, obs_idx, P * T, diffuse_paths, specular_paths_only)
    linear = None
    if emitter_pd is not None and hits.emitter is not None and hits.count:
        linear = _linear_in_pd(H, hits, scale, in_H, obs_idx, emitter_pd, P, T, dtype)
    stats = {"stored_hits": hits.count, "rays": hits.rays, "back_side_hits": int(hits.back_hits)}
    stats.update(photons_emitted=int(hits.emitted.sum()), maps_per_light=K)
    empty = (torch.zeros(0, dtype=torch.long), torch.zeros(0, dtype=dtype), torch.zeros(0, 3, dtype=dtype))
    sel = _lobe_hits(hits, keep, obs_idx, brdf != "lambertian", specular_paths_only)
    if sel.size:
        e_obs, theta_h, weight = _SpecularEntries(
            hits, obs_idx, normals, view_dirs, brdf, sigma, sigma_max, min_cos_light, threads
        ).select(sel, flux)
        if specular_smoothing > 0 and grid is None:
            raise ConfigError("photon.specular_smoothing > 0 needs the texel neighbours (grid = (neighbours,))")
        spread = None
        if specular_smoothing > 0:
            if spreader is None:
                nbrs, gnormals = _grid_parts(grid)
                spreader = SpreadKernel(nbrs, specular_smoothing, gnormals, smoothing_normal)
            spread = lambda obs: spreader(obs, T)  # noqa: E731
        if e_obs.size:
            merged, count = spread_and_merge(e_obs, theta_h, weight, spread, sigma, T, theta_bin, bin_per_sigma)
            empty = (torch.from_numpy(merged[0]), *(torch.from_numpy(x).to(dtype) for x in merged[1:]))
            stats["specular_photons"] = count
    stats["specular_entries"] = int(empty[0].numel())
    irradiance = torch.from_numpy(H.reshape(P, T, 3))
    if smoothing > 0:
        irradiance, smoother = _smooth_irradiance(irradiance, grid, smoother, smoothing, smoothing_normal)
    if linear is not None:
        stats["linear_entries"] = int(linear._nnz())
    # the smoother serves the part linear in Pd only (irradiance_at): a cache without one does not keep it (a copy
    # per cache in the cache's dtype, PhotonCache.to, 0.4 GB on the fold)
    keep_smoother = smoothing > 0 and linear is not None
    return PhotonCache(
        brdf, irradiance.to(dtype), *empty, stats=stats, linear=linear, smoother=smoother if keep_smoother else None
    )


def _several_lights(hits: PhotonHits, sources: LightSources) -> bool:
    """Whether the hits come from more than one light (source s = p * K + k)."""
    if not hits.count:
        return False
    light = hits.source // sources.positions.shape[1]
    return int(light.min()) != int(light.max())


def _build_by_light(hits: PhotonHits, sources: LightSources, args: tuple, kwargs: dict, dtype, smoothing: float):
    """build_cache one light at a time (no part linear in Pd): each light's hits reduced alone in float64 and
    unsmoothed, their irradiance summed (each light's rows hold its own hits' sums, the others' rows 0) and
    smoothed once, their specular entries concatenated in light order (spread_and_merge's order). args, kwargs:
    build_cache's other arguments."""
    P, K = sources.positions.shape[:2]
    grid = kwargs["grid"]
    if kwargs["specular_smoothing"] > 0 and kwargs["spreader"] is None and grid is not None:
        nbrs, gnormals = _grid_parts(grid)  # built once for all the lights
        kwargs["spreader"] = SpreadKernel(nbrs, kwargs["specular_smoothing"], gnormals, kwargs["smoothing_normal"])
    irradiance, entries, spread, brdf = None, [], [], None
    for idx in light_slices(hits.source, K, P):
        if not idx.size:
            continue
        part = build_cache(hits.take(idx), sources, *args, dtype=torch.float64, smoothing=0.0, **kwargs)
        irradiance = part.irradiance if irradiance is None else irradiance.add_(part.irradiance)
        entries.append((part.entry_obs, part.entry_theta_h, part.entry_weight))
        if "specular_photons" in part.stats:
            spread.append(part.stats["specular_photons"])
        brdf = part.brdf
    if smoothing > 0:
        irradiance = _smooth_irradiance(irradiance, grid, kwargs["smoother"], smoothing, kwargs["smoothing_normal"])[0]
    obs, theta, weight = (torch.cat([e[i] for e in entries]) for i in range(3))
    stats = {"stored_hits": hits.count, "rays": hits.rays, "back_side_hits": int(hits.back_hits)}
    stats.update(photons_emitted=int(hits.emitted.sum()), maps_per_light=K)
    if spread:
        stats["specular_photons"] = sum(spread)
    stats["specular_entries"] = int(obs.numel())
    return PhotonCache(brdf, irradiance.to(dtype), obs, theta.to(dtype), weight.to(dtype), stats=stats)


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


def indirect_radiance(
    cache: PhotonCache, kappa: torch.Tensor, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor
) -> torch.Tensor:
    """(P, T, 3) sensor value of the reflected indirect light for pd (T, 3), ps (T, C), sigma (T,);
    differentiable in all three."""
    H = cache.irradiance_at(pd)
    T = H.shape[1]
    out = (pd[None] / math.pi) * H
    if cache.entry_obs.numel():
        # index_select, not sigma[t]: the backward of advanced indexing (index_put_ with accumulate) sums the
        # entries' gradients in a thread-dependent order on CPU, which made fits differ from run to run
        out = out + ps[None] * _specular_sum(cache, sigma.index_select(0, cache.entry_obs % T))
    return kappa * out


def _specular_sum(cache: PhotonCache, entry_sigma: torch.Tensor) -> torch.Tensor:
    """(P, T, 3) S: the specular entries' lobe-weighted sum per observation, each entry's lobe at entry_sigma
    (per entry, or one value for all); the cached specular light is kappa Ps S."""
    P, T, _ = cache.irradiance.shape
    D = brdf_mod.specular_lobe(cache.brdf, cache.entry_theta_h, entry_sigma)
    S = torch.zeros(P * T, 3, dtype=cache.irradiance.dtype, device=cache.irradiance.device)
    return S.index_add(0, cache.entry_obs, D[:, None] * cache.entry_weight).view(P, T, 3)


def specular_per_unit_ps(cache: PhotonCache, kappa: torch.Tensor, sigma) -> torch.Tensor:
    """(P, T, 3) the sensor value of the cached specular interreflection per unit Ps, every texel's lobe at sigma:
    one value (a float or a 0-d tensor) or one per texel ((T,) tensor); what indirect_radiance adds as
    ps * kappa * S."""
    if not cache.entry_obs.numel():
        return torch.zeros_like(cache.irradiance)
    sigma = torch.as_tensor(sigma, dtype=cache.irradiance.dtype, device=cache.irradiance.device)
    if sigma.dim():
        sigma = sigma.index_select(0, cache.entry_obs % cache.irradiance.shape[1])
    return kappa * _specular_sum(cache, sigma)


def texel_cache(cache: PhotonCache, texels: torch.Tensor) -> PhotonCache:
    """The cache of the texels (n,) long only: H0 (P, n, 3) and their specular entries, renumbered to them (what
    specular_per_unit_ps needs; no linear part: Pd's own term is irradiance_at's, evaluated on all texels)."""
    P, T, _ = cache.irradiance.shape
    texels = texels.to(cache.entry_obs.device)
    row = torch.full((T,), -1, dtype=torch.long, device=texels.device)
    row[texels] = torch.arange(len(texels), device=texels.device)
    of = row.index_select(0, cache.entry_obs % T)
    keep = (of >= 0).nonzero()[:, 0]
    return PhotonCache(
        cache.brdf,
        cache.irradiance.index_select(1, texels),
        (cache.entry_obs.index_select(0, keep) // T) * len(texels) + of.index_select(0, keep),
        cache.entry_theta_h.index_select(0, keep),
        cache.entry_weight.index_select(0, keep),
    )


def texel_entries(cache: PhotonCache, kappa: torch.Tensor, texels: torch.Tensor) -> SpecularEntries:
    """The cached specular light per unit Ps of the texels (n,) long as SpecularEntries (obs p * n + j, the weights
    times kappa): what specular_per_unit_ps(texel_cache(cache, texels), kappa, sigma) sums."""
    sub = texel_cache(cache, texels)
    return SpecularEntries(sub.entry_obs, sub.entry_theta_h, sub.entry_weight * kappa.to(sub.entry_weight))


def indirect_radiance_reference(
    hits: PhotonHits,
    sources: LightSources,
    areas,
    normals,
    view_dirs,
    brdf: str,
    kappa,
    pd,
    ps,
    sigma,
    min_cos_light: float,
) -> torch.Tensor:
    """The same estimate straight from the stored photons and brdf.brdf (slow, obvious; tests only):
    kappa * sum_k f_t(wi_k, v_pt) Phi_k w_k / A_t, with the specular part dropped at n.wi <= min_cos_light
    and where the texel faces away from the camera (the diffuse part counts every stored photon: it reached
    the surface, even where the texel's smoothed normal disagrees)."""
    P, K = sources.positions.shape[:2]
    T = pd.shape[0]
    out = torch.zeros(P, T, 3, dtype=pd.dtype)
    ps3 = ps.expand(T, 3)
    for i in range(hits.count):
        p, k, t = int(hits.source[i] // K), int(hits.source[i] % K), int(hits.texel[i])
        n = normals[t]
        v = view_dirs[p, t] if view_dirs.dim() == 3 else view_dirs[t]
        wi = torch.as_tensor(hits.direction[i], dtype=pd.dtype)
        cos_i = float(n @ wi)
        f = pd[t] / math.pi  # every stored photon reached the surface
        if cos_i > min_cos_light and float(n @ v) > 0:
            f = f + brdf_mod.brdf(brdf, n, wi, v, torch.zeros_like(pd[t]), ps3[t], sigma[t])
        w = 1.0 if hits.density_weight is None else float(hits.density_weight[i])
        out[p, t] += f * torch.as_tensor(hits.power[i] * w * sources.weights[k, t] / float(areas[t]), dtype=pd.dtype)
    return kappa * out
