"""One refresh of Method III's photon cache: trace photons with the current parameters, reduce them to the cache.

Images that share a light (mesh_views: several views per light) share its photons: the photons of a light depend on
the light and the parameters only, so each distinct light (its map positions and intensity, compared exactly) is
traced once per refresh and its hits are counted for every image of that light, in which the cache's view-dependent
terms are then reduced (build_cache's image_light: a light's hits, held once, are reduced once for the irradiance of
all its images and once per image for the specular entries). A capture whose lights all differ (the cylindrical
scan's co-rotating lights) traces exactly as before. Where the cache takes the all-diffuse paths from the radiosity
level and gathers their specular reflection, the trace stores only the hits of paths with a specular scattering
(the others carry no weight there).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from torchrefl.core.distinct_rows import distinct_rows
from torchrefl.core.memory import release_free_memory
from torchrefl.core.progress import bar
from torchrefl.transport.cache_build import build_cache
from torchrefl.transport.light_maps import LightSources
from torchrefl.transport.photon_cache import PhotonCache
from torchrefl.transport.photon_density import SpreadKernel, smoothing_matrix
from torchrefl.transport.photon_material import TexelMaterial
from torchrefl.transport.photon_trace import PhotonTracer
from torchrefl.transport.specular_gather import SpecularGather

#: photons per distinct light of the pilot trace that measures the stored hits per photon before the first refresh
PILOT_PHOTONS = 20_000
#: the pilot's refresh number in the tracer's random streams (no refresh uses it)
PILOT_REFRESH = 1 << 20


@dataclass
class PhotonRefresh:
    """Everything a photon cache refresh needs besides the parameters: traces photons at given Pd, Ps, sigma
    and reduces them to the cache of indirect light per (light, texel)."""

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
    grid: tuple | None = None  # (neighbours[, normals (T, 3)]): the Surface's, for the density kernels
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
            neighbours = self.grid[0]
            normals = self.grid[1] if len(self.grid) > 1 else None
            self._smoother = smoothing_matrix(
                neighbours,
                self.smoothing,
                None if normals is None else np.asarray(normals, dtype=np.float64),
                self.smoothing_normal,
            )
        return self._smoother

    def spreader(self) -> SpreadKernel | None:
        """The specular entries' spread (photon_density.SpreadKernel), built on first use and kept for every refresh."""
        if self.specular_smoothing <= 0 or self.grid is None:
            return None
        if getattr(self, "_spreader", None) is None:
            normals = self.grid[1] if len(self.grid) > 1 else None
            self._spreader = SpreadKernel(self.grid[0], self.specular_smoothing, normals, self.smoothing_normal)
        return self._spreader

    @property
    def _gathers_diffuse_paths(self) -> bool:
        """Whether the cache takes the all-diffuse paths' light from the radiosity level and gathers their specular
        reflection (specular_gather): then only the hits of paths with a specular scattering count, and only they
        are stored."""
        return self.radiosity_irradiance is not None and self.specular_gather is not None

    def hits_per_photon(self, pd, ps, sigma, photons: int = PILOT_PHOTONS) -> float:
        """Stored hits per photon emitted, measured by a pilot trace of `photons` photons per distinct light with
        these parameters (what a refresh stores: PhotonRefresh.cache's trace)."""
        K = self.sources.positions.shape[1]
        first, _ = distinct_lights(self.sources)
        per_map = max(1, math.ceil(min(photons, self.photons_per_light) / K))
        hits = self.tracer.trace(
            self.sources.positions[first].reshape(-1, 3),
            np.repeat(self.sources.intensity[first], K, 0),
            per_map,
            TexelMaterial.from_tensors(*self._scattering(pd, ps, sigma)),
            seed=self.seed,
            refresh=PILOT_REFRESH,
            specular_paths_only=self._gathers_diffuse_paths,
        )
        return hits.count / max(1, len(first) * K * per_map)

    def _scattering(self, pd, ps, sigma) -> tuple:
        """The parameters the texels scatter with (with emitter_source: each texel its source's)."""
        if self.emitter_source is None:
            return pd, ps, sigma
        src = self.emitter_source.to(pd.device)
        return tuple(x[src] if x.shape[0] == src.shape[0] else x for x in (pd, ps, sigma))  # a shared lobe stays

    def cache(self, pd, ps, sigma, refresh: int, progress: bool = False) -> PhotonCache:
        """Trace photons with these parameters and reduce them to the cache."""
        release_free_memory()  # the heap's free pages would add to the tracing's peak
        pd, ps, sigma = self._scattering(pd, ps, sigma)
        P, K = self.sources.positions.shape[:2]
        per_map = max(1, math.ceil(self.photons_per_light / K))
        mat = TexelMaterial.from_tensors(pd, ps, sigma)
        first, light_of = distinct_lights(self.sources)
        U = len(first)
        with bar(U * K * per_map, f"photons (refresh {refresh})", progress, unit="ph") as pb:
            last = [0]

            def tick(done, total):
                pb.update(done - last[0])
                last[0] = done

            start = time.perf_counter()
            hits = self.tracer.trace(
                self.sources.positions[first].reshape(-1, 3),
                np.repeat(self.sources.intensity[first], K, 0),
                per_map,
                mat,
                seed=self.seed,
                refresh=refresh,
                progress=tick,
                specular_paths_only=self._gathers_diffuse_paths,
            )
            traced = time.perf_counter()
        cache = build_cache(
            hits,
            self.sources,
            self.tracer.areas,
            self.tracer.normals,
            self.view_dirs,
            self.keep,
            self.tracer.brdf,
            sigma.detach().cpu().double().numpy(),
            self.sigma_max,
            self.min_cos_light,
            dtype=self.dtype,
            smoothing=self.smoothing,
            grid=self.grid,
            emitter_pd=mat.pd if self.linear_emitters else None,
            smoothing_normal=self.smoothing_normal,
            specular_smoothing=self.specular_smoothing,
            threads=self.tracer.tracer.threads,
            smoother=self.smoother(),
            spreader=self.spreader(),
            diffuse_paths=self.radiosity_irradiance is None,
            specular_paths_only=self._gathers_diffuse_paths,
            image_light=light_of if U < P else None,
        )
        del hits  # reduced: not alive beside the radiosity solve and the gather
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
            cache.exact_irradiance = H_rad.to(cache.irradiance.dtype)
            if self.specular_gather is not None:
                cache = self._add_gather(cache, radiance, weights, sigma, refresh)
        cache.stats["traced_lights"] = U
        cache.stats["trace_s"] = round(traced - start, 3)
        cache.stats["reduce_s"] = round(time.perf_counter() - traced, 3)
        return cache.to(self.dtype, self.device)

    def _add_gather(self, cache: PhotonCache, radiance, weights, sigma, refresh: int) -> PhotonCache:
        """The cache with the gathered specular entries of the all-diffuse paths appended (specular_gather), from
        the radiosity level's radiance (P, K, T, 3) and map weights (K, T)."""
        start = time.perf_counter()
        sig = sigma.detach().cpu().double().numpy()
        samples = self.specular_gather.directions(sig, refresh)
        obs, theta, weight = self.specular_gather.entries(
            samples, radiance.double().numpy(), weights.double().numpy(), sig
        )
        dt = cache.entry_theta_h.dtype
        cache.entry_obs = torch.cat([cache.entry_obs, torch.from_numpy(obs)])
        cache.entry_theta_h = torch.cat([cache.entry_theta_h, torch.from_numpy(theta).to(dt)])
        cache.entry_weight = torch.cat([cache.entry_weight, torch.from_numpy(weight).to(dt)])
        cache.stats.update(
            gather_rays=int(samples.rays), gather_entries=int(obs.size), gather_s=round(time.perf_counter() - start, 3)
        )
        return cache


def distinct_lights(sources: LightSources) -> tuple[np.ndarray, np.ndarray]:
    """The distinct lights among the images of `sources`: first (U,) the first image of each distinct light (its
    K map positions and intensity equal bit for bit), light_of (P,) each image's distinct light, 0..U-1."""
    P = sources.positions.shape[0]
    return distinct_rows(np.concatenate([sources.positions.reshape(P, -1), sources.intensity.reshape(P, -1)], axis=1))
