"""Method III's outer loop (dissertation Ch.5): refresh the photon cache, refit, keep the best.

Each outer iteration re-traces the photons with the current parameters (the cache is then fixed)
and refines the texel tensors against local + cached indirect light:
- joint: all of Pd, Ps, sigma on every fitted observation;
- seed: the dissertation's alternation, process (a) Pd alone on the T_diff observations (on all
  fitted observations of a texel that has none in T_diff), then process (b) Ps and sigma alone on
  the T_spec and T_none observations.
With a `reinitialise` callback (photon.reinitialise) every outer iteration first restarts from the
closed forms on the images minus the cached indirect light (the photon analogue of Method II's
eq. 4.9-4.11), so the start no longer carries the interreflection that the local start absorbed.
The parameters are scored after every refresh by the mean absolute image difference (8-bit) over the
fitted observations, with the cache traced at exactly those parameters, and the best are kept: the
init is scored at refresh 0, the result of outer iteration k at refresh k + 1.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from torchrefl.errors import ConfigError
from torchrefl.fit.classify import T_DIFF, T_NONE, T_SPEC
from torchrefl.fit.params import TexelParams, inverse_softplus_b
from torchrefl.fit.refine import refine
from torchrefl.core.progress import bar
from torchrefl.transport.photon_level import LightSources, PhotonCache, build_cache, indirect_radiance, smoothing_matrix
from torchrefl.transport.photon_trace import PhotonTracer, TexelMaterial
from torchrefl.transport.specular_gather import SpecularGather

SCHEDULES = ("joint", "seed")


@dataclass
class PhotonLevel:
    """Everything a cache refresh needs besides the parameters."""

    tracer: PhotonTracer
    sources: LightSources
    view_dirs: torch.Tensor
    keep: torch.Tensor
    photons_per_light: int
    sigma_max: float
    min_cos_light: float
    seed: int
    dtype: torch.dtype
    device: torch.device
    smoothing: float = 0.0
    grid: tuple | None = None
    linear_emitters: bool = False
    smoothing_normal: float = 0.0
    specular_smoothing: float = 0.0
    # photon.diffuse_paths 'radiosity': H(pd) -> (P, T, 3) the all-diffuse paths' irradiance from the radiosity
    # level (noise-free; the photons then carry only paths with a specular scattering into H)
    radiosity_irradiance: Callable | None = None
    # photon.specular_gather: the gatherer and pd -> (H (P, T, 3) as radiosity_irradiance gives it, radiance
    # (P, K, T, 3), map weights (K, T)) from one radiosity solve: the level's outgoing all-diffuse radiance per
    # emitter map (the photons' specular entries then keep only the paths with a specular scattering)
    specular_gather: SpecularGather | None = None
    radiosity_radiance: Callable | None = None
    # fit.emitter_fill: (T,) index of the texel whose parameters each texel scatters with (None = its own)
    emitter_source: torch.Tensor | None = None

    def smoother(self) -> torch.Tensor | None:
        """The density-estimation kernel as a sparse operator, built on first use and kept for every refresh."""
        if self.smoothing <= 0 or self.grid is None:
            return None
        if getattr(self, "_smoother", None) is None:
            index, shape = self.grid[0], self.grid[1]
            normals = self.grid[2] if len(self.grid) > 2 else None
            self._smoother = smoothing_matrix(np.asarray(index), shape, self.smoothing,
                                              None if normals is None else np.asarray(normals, dtype=np.float64),
                                              self.smoothing_normal)
        return self._smoother

    def cache(self, pd, ps, sigma, refresh: int, progress: bool = False) -> PhotonCache:
        """Trace photons with these parameters and reduce them to the cache."""
        if self.emitter_source is not None:
            src = self.emitter_source.to(pd.device)
            pd, ps, sigma = (x[src] if x.shape[0] == src.shape[0] else x for x in (pd, ps, sigma))   # a shared lobe stays
        P, K = self.sources.positions.shape[:2]
        per_map = max(1, math.ceil(self.photons_per_light / K))
        mat = TexelMaterial.from_tensors(pd, ps, sigma)
        with bar(P * K * per_map, f"photons (refresh {refresh})", progress, unit="ph") as pb:
            last = [0]

            def tick(done, total):
                pb.update(done - last[0])
                last[0] = done

            start = time.perf_counter()
            hits = self.tracer.trace(self.sources.positions.reshape(-1, 3), np.repeat(self.sources.intensity, K, 0),
                                     per_map, mat, seed=self.seed, refresh=refresh, progress=tick)
            traced = time.perf_counter()
        cache = build_cache(hits, self.sources, self.tracer.areas, self.tracer.normals, self.view_dirs, self.keep,
                            self.tracer.brdf, sigma.detach().cpu().double().numpy(), self.sigma_max,
                            self.min_cos_light, dtype=self.dtype, smoothing=self.smoothing, grid=self.grid,
                            emitter_pd=mat.pd if self.linear_emitters else None, smoothing_normal=self.smoothing_normal,
                            specular_smoothing=self.specular_smoothing, threads=self.tracer.tracer.threads,
                            smoother=self.smoother(), diffuse_paths=self.radiosity_irradiance is None,
                            specular_paths_only=self.specular_gather is not None)
        if self.radiosity_irradiance is not None:
            pd_cpu = pd.detach().cpu().to(cache.irradiance.dtype)
            with torch.no_grad():
                if self.specular_gather is not None:
                    H_rad, radiance, weights = self.radiosity_radiance(pd_cpu)
                else:
                    H_rad = self.radiosity_irradiance(pd_cpu)
            cache.stats["radiosity_irradiance_mean"] = float(H_rad.mean())
            cache.stats["photon_irradiance_mean"] = float(cache.irradiance.mean())
            cache.irradiance = cache.irradiance + H_rad.to(cache.irradiance.dtype)
            if self.specular_gather is not None:
                cache = self._add_gather(cache, radiance, weights, sigma, refresh)
        cache.stats["trace_s"] = round(traced - start, 3)
        cache.stats["reduce_s"] = round(time.perf_counter() - traced, 3)
        return cache.to(self.dtype, self.device)


    def _add_gather(self, cache: PhotonCache, radiance, weights, sigma, refresh: int) -> PhotonCache:
        """The cache with the gathered specular entries of the all-diffuse paths appended (specular_gather), from
        the radiosity level's radiance (P, K, T, 3) and map weights (K, T)."""
        start = time.perf_counter()
        sig = sigma.detach().cpu().double().numpy()
        samples = self.specular_gather.directions(sig, refresh)
        obs, theta, weight = self.specular_gather.entries(samples, radiance.double().numpy(), weights.double().numpy(), sig)
        dt = cache.entry_theta_h.dtype
        cache.entry_obs = torch.cat([cache.entry_obs, torch.from_numpy(obs)])
        cache.entry_theta_h = torch.cat([cache.entry_theta_h, torch.from_numpy(theta).to(dt)])
        cache.entry_weight = torch.cat([cache.entry_weight, torch.from_numpy(weight).to(dt)])
        cache.stats.update(gather_rays=int(samples.rays), gather_entries=int(obs.size),
                           gather_s=round(time.perf_counter() - start, 3))
        return cache


BACK_HIT_WARNING = 0.03      # share of photon rays ending on the back of the scanned surface that draws a warning


def image_score(pred: torch.Tensor, intensity: torch.Tensor, mask: torch.Tensor) -> float:
    """Mean absolute difference in 8-bit DN over the masked observations."""
    return float(((pred - intensity).abs() * 255.0)[mask].mean())


def run_schedule(params: TexelParams, level: PhotonLevel, local_predict: Callable, kappa: torch.Tensor,
                 make_objective: Callable, intensity: torch.Tensor, fit_mask: torch.Tensor, classes: torch.Tensor, *,
                 schedule: str, outer: int, optimizer: str, iterations: int, learning_rate: float,
                 progress: bool = True, log=print, reinitialise: Callable | None = None, damping: float = 0.0) -> dict:
    """Run the outer loop in place on params (left at the best parameters).

    local_predict(pd, ps, sigma) -> (P, T, 3) direct light; make_objective(predict, weight) -> Objective;
    fit_mask (P, T) fitted observations; classes (P, T) observation classes (for the seed schedule);
    reinitialise(direct_only (P, T, 3)) -> (pd, ps, sigma) or None; damping: after each refit, Pd moves
    only (1 - damping) of the way from the Pd the cache was traced with (under-relaxation of the
    fixed point between cache and fit, which oscillates where texels light each other strongly).
    Returns history (losses), scores (one per refresh), best (refresh index), cache (at the best
    parameters) and predict (the photon-level model with that cache).
    """
    if schedule not in SCHEDULES:
        raise ConfigError(f"photon.schedule: unknown schedule '{schedule}', expected one of {', '.join(SCHEDULES)}")
    device = intensity.device
    fit_mask = fit_mask.to(device)
    cls = classes.to(device)
    diffuse = fit_mask & (cls == T_DIFF)
    no_diffuse = ~diffuse.any(0)                  # texels without a T_diff observation: Pd from all of theirs
    masks = {"all": fit_mask, "diffuse": diffuse | (fit_mask & no_diffuse[None]),
             "specular": fit_mask & ((cls == T_SPEC) | (cls == T_NONE))}
    model_for = lambda c: (lambda pd, ps, sg: local_predict(pd, ps, sg) + indirect_radiance(c, kappa, pd, ps, sg))
    history: list[float] = []
    scores: list[float] = []
    best = (math.inf, -1, None, None)
    for k in range(outer + 1):
        with torch.no_grad():
            values = params.values()
            cache = level.cache(*values, refresh=k, progress=progress)
            model = model_for(cache)
            score = image_score(model(*values), intensity, fit_mask)
        scores.append(score)
        log(f"photon refresh {k}: {cache.stats['photons_emitted']} photons, {cache.stats['stored_hits']} stored hits, "
            f"{cache.stats['specular_entries']} specular entries"
            + (f" (+ {cache.stats['gather_entries']} gathered from {cache.stats['gather_rays']} rays)"
               if "gather_entries" in cache.stats else "") + f"; image difference {score:.4f} DN")
        back = cache.stats.get("back_side_hits", 0) / max(cache.stats.get("rays", 0), 1)
        if k == 0 and back > BACK_HIT_WARNING:
            log(f"warning: {back:.0%} of the photon rays hit the back of the scanned surface: light reaches parts of the "
                "object the scan does not cover (holes, unscanned sides) and their interreflection is not modelled, so "
                "the fit attributes the missing indirect light to Pd (see metrics.json photon.cache.back_side_hits)")
        if score < best[0]:
            best = (score, k, {n: p.detach().clone() for n, p in params.named_parameters()}, cache)
        if k == outer:
            break
        if reinitialise is not None:
            with torch.no_grad():
                direct_only = intensity - indirect_radiance(cache, kappa, *values)
            params.assign(*(x.to(intensity) for x in reinitialise(direct_only)))
        if schedule == "joint":
            steps = [(None, masks["all"], "joint")]
        else:
            steps = [([params.raw_pd], masks["diffuse"], "(a) Pd on T_diff"),
                     ([params.raw_ps, params.raw_sigma], masks["specular"], "(b) Ps, sigma on T_spec + T_none")]
        for train, weight, name in steps:
            if not bool(weight.any()):
                log(f"photon outer {k + 1}: {name} skipped (no observation)")
                continue
            with bar(iterations, f"fit {k + 1}/{outer} {name}", progress) as pb:
                history += refine(params, make_objective(model, weight), optimizer, iterations, learning_rate,
                                  progress=pb, train=train)
        if damping > 0:                 # Pd only: Ps and sigma keep their refit values exactly
            with torch.no_grad():
                params.raw_pd.copy_(inverse_softplus_b(damping * values[0] + (1.0 - damping) * params.pd()))
    _, k_best, state, cache = best
    with torch.no_grad():
        for n, p in params.named_parameters():
            p.copy_(state[n])
    log(f"photon level: kept the parameters of refresh {k_best} (image difference {best[0]:.4f} DN)")
    return {"history": history, "scores": scores, "best": k_best, "cache": cache, "predict": model_for(cache)}
