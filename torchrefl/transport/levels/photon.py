"""Method III (dissertation Ch.5): direct light plus diffuse and specular interreflection by photon mapping.

Each refresh re-traces the photons with the current parameters into a cache of indirect light per
(light, texel) (transport.photon_refresh); between refreshes the fit refines the texel tensors against
local + cached indirect light (photon.schedule joint: all parameters on every fitted observation; seed:
the dissertation's alternation, (a) Pd on T_diff, then (b) Ps and sigma on T_spec and T_none). After each
refit Pd keeps photon.damping of the Pd the cache was traced with. From refresh AVERAGE_FROM on the cache
averages the new trace with the previous one (transport.cache_average.average_caches): half the photon noise in
what the refits fit. Every refresh scores the parameters by the mean absolute image difference (8-bit) over the
fitted observations with its cache, and the best are kept: the start is scored at refresh 0, refit k at refresh k.

With photon.diffuse_paths: radiosity the level composes a RadiosityLevel: the all-diffuse paths' irradiance
comes from its solution at each refresh, the photons carry only the paths with a specular scattering.
"""

from __future__ import annotations

import math
import time

import torch

from torchrefl.core.memory import release_free_memory
from torchrefl.core.observation_classes import T_DIFF, T_NONE, T_SPEC
from torchrefl.core.params import inverse_softplus_b
from torchrefl.core.rays import RayTracer
from torchrefl.transport.cache_average import average_caches
from torchrefl.transport.final_traces import fresh_traces, image_variance, trace_variance
from torchrefl.transport.levels.base import IndirectTerms, LevelInputs, RefitStep, TransportLevel
from torchrefl.transport.levels.radiosity import SMOOTHING_NORMAL, RadiosityLevel
from torchrefl.transport.light_maps import light_sources
from torchrefl.transport.memory_estimate import check_photon_memory
from torchrefl.transport.pd_precision import median_pd_std
from torchrefl.transport.photon_cache import (
    indirect_radiance,
    specular_per_unit_ps,
    texel_cache,
    texel_entries,
)
from torchrefl.transport.photon_density import (
    KERNEL_PHOTONS,
    MAX_AUTO_SMOOTHING,
    density_kernels,
    kernel_std,
    photons_for_kernel,
)
from torchrefl.transport.photon_refresh import PhotonRefresh, distinct_lights
from torchrefl.transport.photon_trace import PhotonTracer
from torchrefl.transport.specular_gather import SpecularGather

#: share of photon rays ending on the back of the scanned surface that draws a warning
BACK_HIT_WARNING = 0.03
#: from this refresh on the cache averages the new trace with the previous one (the first refits move the
#: parameters far, so refresh 1's trace would mix in the start's light)
AVERAGE_FROM = 2


class _LazySpecular:
    """sigma (n,) -> (P, n, 3) the specular factor of some texels (specular_per_unit_ps), their cache (texel_cache)
    cut on the first call: a model whose factor is never evaluated (the LM's closed form takes the entries) cuts
    none."""

    def __init__(self, cache, kappa: torch.Tensor, texels: torch.Tensor):
        self.cache, self.kappa, self.texels, self.sub = cache, kappa, texels, None

    def __call__(self, sigma: torch.Tensor) -> torch.Tensor:
        if self.sub is None:
            self.sub = texel_cache(self.cache, self.texels)
        return specular_per_unit_ps(self.sub, self.kappa, sigma)


def image_score(pred: torch.Tensor, intensity: torch.Tensor, mask: torch.Tensor) -> float:
    """Mean absolute difference in 8-bit DN over the masked observations."""
    return float(((pred - intensity).abs() * 255.0)[mask].mean())


class PhotonLevel(TransportLevel):
    name = "photon"

    def __init__(self, inputs: LevelInputs, radiosity: RadiosityLevel, reason: str | None = None):
        """radiosity: the capture's RadiosityLevel (prepared before this level), for Method II's start and, with
        photon.diffuse_paths: radiosity, the all-diffuse paths; reason: model_reason when another rule chose this
        level."""
        super().__init__(inputs)
        pc = inputs.cfg.photon
        self.radiosity = radiosity
        self.hybrid = pc.diffuse_paths == "radiosity"
        self.refits = pc.outer_iterations
        self._reason = reason
        self._local = inputs.local_predict()
        self.emitter_source = None
        self.scores: list[float] = []
        self.refresh_at: list[float] = []  # seconds from the start of refresh 0 to the end of each refresh
        self._clock = time.perf_counter()  # reset at refresh 0; a resumed fit counts from the level's creation
        self.pd_change: list[float] = []  # rms change of Pd since the previous refresh, per refresh from 1 on
        self.pd_std: list[float] = []  # Pd's median std at each convergence test (refresh AVERAGE_FROM + 1 on)
        self.cache = None
        self._last_trace = None  # the latest refresh's own trace (the cache may average two)
        self._photon_noise = (None, None)  # finish's (one trace's photon variance, the images' noise variance)
        self.refresher: PhotonRefresh | None = None
        self.smoothing = self.specular_smoothing = 0.0  # the density kernels' std in texels, set by prepare
        self._best = (math.inf, -1, None, None)

    @property
    def reason(self) -> str:
        if self._reason is not None:
            return self._reason
        text = "fit.model is 'photon': direct light plus diffuse and specular interreflection by photon tracing"
        return (
            text
            + "; started from Method II"
            + ("; all-diffuse paths from the radiosity solution" if self.hybrid else "")
            + " ("
            + self.radiosity.note
            + ")"
        )

    def use_emitters(self, source: torch.Tensor) -> None:
        self.emitter_source = source
        self.radiosity.use_emitters(source)
        if self.refresher is not None:  # prepared before the start knew its fitted texels
            self.refresher.emitter_source = source

    def start(self, init):
        return self.radiosity.start(init)

    def prepare(self) -> None:
        """The photon tracer over the surface's mesh (its hits map a hit to a texel) and the light sources; logs the
        schedule."""
        inp = self.inputs
        cfg, surface, obs = inp.cfg, inp.surface, inp.obs
        pc, rc = cfg.photon, cfg.reflectance
        tracer = RayTracer(surface.mesh_vertices, surface.mesh_faces, threads=cfg.threads)
        offset = 1e-3 * math.sqrt(float(surface.areas.double().median()))
        ptracer = PhotonTracer(
            tracer,
            surface.texel_index.numpy(),
            surface.positions.double().numpy(),
            surface.normals.double().numpy(),
            rc.brdf,
            hits=surface.hits,
            offset=offset,
            min_bounces=1,
            max_bounces=16,
        )
        sources = light_sources(surface, obs, pc.light_maps)
        view = obs.view_dirs_full() if obs.view_dir.dim() == 3 else obs.view_dir
        keep = inp.fit_mask | inp.eval_mask
        gather = None
        if pc.specular_gather > 0 and self.hybrid:  # it gathers the radiosity level's light: unused with photons
            gather = SpecularGather(
                ptracer,
                view.double().numpy(),
                keep.cpu().numpy(),
                rc.brdf,
                pc.specular_gather,
                rc.min_cos_light,
                rc.sigma_max,
                seed=cfg.seed,
            )
        kernel_note, kernel_warning = self._kernels(surface.num_texels)
        self.refresher = PhotonRefresh(
            ptracer,
            sources,
            view.double(),
            keep,
            pc.photons_per_light,
            rc.sigma_max,
            rc.min_cos_light,
            cfg.seed,
            obs.intensity.dtype,
            inp.device,
            smoothing=self.smoothing,
            grid=(surface.neighbours, surface.normals.double()),
            smoothing_normal=SMOOTHING_NORMAL,
            specular_smoothing=self.specular_smoothing,
            radiosity_irradiance=self.radiosity.indirect if self.hybrid else None,
            specular_gather=gather,
            radiosity_radiance=self.radiosity.radiance if gather is not None else None,
            emitter_source=self.emitter_source,
        )
        inp.log(
            f"photon level: {sources.num_maps} photon map(s) per light, {pc.photons_per_light} photons "
            f"per light and refresh, {pc.outer_iterations} outer iterations, schedule {pc.schedule}, "
            + (
                "all-diffuse paths from the radiosity level, photons for the paths with a specular scattering"
                if self.hybrid
                else "every path from photons"
            )
            + f", Pd damping {pc.damping:g} between refreshes; {kernel_note}"
        )
        if kernel_warning:
            inp.log(kernel_warning)

    def _kernels(self, texels: int) -> tuple[str, str | None]:
        """Set the density kernels' std in texels (photon.smoothing, specular_smoothing; null: automatic, capped);
        returns the log's note on them and a warning when the cap leaves the cache noisier than the target."""
        pc = self.inputs.cfg.photon
        n = pc.photons_per_light
        auto = kernel_std(n, texels, KERNEL_PHOTONS)
        self.smoothing, self.specular_smoothing = density_kernels(n, texels, pc.smoothing, pc.specular_smoothing)
        note = f"density kernels {self.smoothing:.2f} texels (irradiance), {self.specular_smoothing:.2f} (specular)"
        if pc.smoothing is None and auto > 1.25 * MAX_AUTO_SMOOTHING:  # under 64 % of the kernel's photons
            need = photons_for_kernel(MAX_AUTO_SMOOTHING, texels, KERNEL_PHOTONS)
            return note, (
                f"warning: at {n} photons per light the automatic density kernel would be {auto:.1f} texels, capped "
                f"at {MAX_AUTO_SMOOTHING:g}, so the photon cache is noisier than the default target: "
                f"photon.photons_per_light: {need} reaches it"
            )
        return note, None

    def predict(self, pd, ps, sigma):
        kappa = self.inputs.obs.kappa.to(pd.device)
        return self._local(pd, ps, sigma) + indirect_radiance(self.cache, kappa, pd, ps, sigma)

    def indirect_terms(self, pd: torch.Tensor) -> IndirectTerms:
        kappa = self.inputs.obs.kappa.to(pd.device)
        cache = self.cache
        with torch.no_grad():
            diffuse = kappa * cache.irradiance_at(pd) / math.pi
        return IndirectTerms(
            diffuse,
            lambda sigma: specular_per_unit_ps(cache, kappa, sigma),
            lambda texels: _LazySpecular(cache, kappa, texels),
            lambda texels: texel_entries(cache, kappa, texels),
        )

    def steps(self, k: int) -> list[RefitStep]:
        inp, pc = self.inputs, self.inputs.cfg.photon
        iterations = inp.cfg.fit.iterations
        device = inp.device
        fit_mask, cls = inp.fit_mask.to(device), inp.classes.to(device)
        outer = self.refits
        if pc.schedule == "joint":
            steps = [RefitStep(None, fit_mask, f"fit {k + 1}/{outer} joint", iterations)]
        else:
            diffuse = fit_mask & (cls == T_DIFF)
            no_diffuse = ~diffuse.any(0)  # texels without a T_diff observation: Pd from all of theirs
            steps = [
                RefitStep(
                    ["raw_pd"],
                    diffuse | (fit_mask & no_diffuse[None]),
                    f"fit {k + 1}/{outer} (a) Pd on T_diff",
                    iterations,
                ),
                RefitStep(
                    ["raw_ps", "raw_sigma"],
                    fit_mask & ((cls == T_SPEC) | (cls == T_NONE)),
                    f"fit {k + 1}/{outer} (b) Ps, sigma on T_spec + T_none",
                    iterations,
                ),
            ]
        kept = [s for s in steps if bool(s.mask.any())]
        for s in steps:
            if s not in kept:
                inp.log(f"photon outer {k + 1}: {s.label.split(' ', 2)[2]} skipped (no observation)")
        return kept

    def refresh(self, params, k: int) -> None:
        """Damp Pd towards the Pd the last cache was traced with, trace the cache at the parameters, score them."""
        inp, pc = self.inputs, self.inputs.cfg.photon
        if k == 0:
            self._clock = time.perf_counter()
        if k > 0 and pc.damping > 0:  # Pd only: Ps and sigma keep their refit values exactly
            with torch.no_grad():
                params.raw_pd.copy_(inverse_softplus_b(pc.damping * self._traced_pd + (1.0 - pc.damping) * params.pd()))
        with torch.no_grad():
            values = params.values()
            if k > 0:
                self.pd_change.append(float((values[0] - self._traced_pd).double().square().mean().sqrt()))
            self._traced_pd = values[0]
            if k == 0:
                self._check_memory(values)
            trace = self.refresher.cache(*values, refresh=k, progress=inp.cfg.output.progress)
            if k >= AVERAGE_FROM:
                sigma = values[2].detach().cpu().double().numpy()
                release_free_memory()  # the trace's freed temporaries would add to the average's peak
                self.cache = average_caches(self._last_trace, trace, sigma)
            else:
                self.cache = trace
            self._last_trace = trace
            intensity = inp.obs.intensity.to(inp.device)
            score = image_score(self.predict(*values), intensity, inp.fit_mask.to(inp.device))
        release_free_memory()  # before the re-estimation and the refit
        self.scores.append(score)
        self.refresh_at.append(round(time.perf_counter() - self._clock, 2))
        stats = self.cache.stats
        inp.log(
            f"photon refresh {k}: {stats['photons_emitted']} photons traced for "
            f"{stats.get('traced_lights', '?')} distinct lights, {stats['stored_hits']} stored hits, "
            f"{stats['specular_entries']} specular entries"
            + (
                f" (+ {stats['gather_entries']} gathered from {stats['gather_rays']} rays)"
                if "gather_entries" in stats
                else ""
            )
            + (
                f", averaged with the previous trace into {stats['averaged_entries']} entries"
                if "averaged_entries" in stats
                else ""
            )
            + f"; image difference {score:.4f} DN"
        )
        back = stats.get("back_side_hits", 0) / max(stats.get("rays", 0), 1)
        if k == 0 and back > BACK_HIT_WARNING:
            inp.log(
                f"warning: {back:.0%} of the photon rays hit the back of the scanned surface: light reaches parts "
                "of the object the scan does not cover (holes, unscanned sides) and their interreflection is not "
                "modelled, so the fit attributes the missing indirect light to Pd (see metrics.json "
                "photon.cache.back_side_hits)"
            )
        if score < self._best[0]:
            self._best = (score, k, {n: p.detach().clone() for n, p in params.named_parameters()}, self.cache)

    def _check_memory(self, values) -> None:
        """Refuse (MemoryLimitError) refreshes that would not fit, with the stored hits per photon a pilot trace
        measures at the start's parameters."""
        inp = self.inputs
        lights = len(distinct_lights(self.refresher.sources)[0])
        traced = lights * self.refresher.sources.num_maps
        per_map = math.ceil(self.refresher.photons_per_light / self.refresher.sources.num_maps)
        hits = self.refresher.hits_per_photon(*values)
        check_photon_memory(hits, traced * per_map, inp.obs.num_lights, inp.surface.num_texels, inp.log, lights)

    def converged(self, params) -> str | None:
        """After a refit of an averaged cache, before its refresh: done when the refit moved Pd (RMS, as the refresh
        would damp it) by less than the median std the observations give it (transport.pd_precision)."""
        k = len(self.scores)  # the refit just run follows refresh k - 1
        if k <= AVERAGE_FROM:
            return None
        inp = self.inputs
        pd, ps, sigma = params.values()
        with torch.no_grad():
            moved = (pd - self._traced_pd).double().square().mean().sqrt()
            change = float((1.0 - inp.cfg.photon.damping) * moved)
        std = median_pd_std(
            self.texel_model(pd), pd, ps, sigma, inp.obs.intensity.to(inp.device), inp.fit_mask.to(inp.device)
        )
        self.pd_std.append(std)
        if change >= std:
            return None
        self.pd_change.append(change)  # the refit's change is reported although no refresh follows
        return (
            f"refit {k} moved Pd by {change:.2g} (RMS), less than its median std {std:.2g}: the outer loop has "
            "converged"
        )

    def state(self) -> dict:
        return {
            "scores": list(self.scores),
            "pd_change": list(self.pd_change),
            "pd_std": list(self.pd_std),
            "cache": self.cache,
            "last_trace": self._last_trace,
            "traced_pd": self._traced_pd,
            "best": self._best,
        }

    def restore(self, state: dict) -> None:
        self.scores, self.pd_change = list(state["scores"]), list(state["pd_change"])
        self.pd_std = list(state.get("pd_std", []))
        self.cache, self._last_trace = state["cache"], state["last_trace"]
        self._traced_pd, self._best = state["traced_pd"], state["best"]

    def finish(self, params) -> None:
        """Keep the parameters (and the cache) of the best-scored refresh; measure one trace's photon noise from the
        last averaged refresh (transport.final_traces), which decides how many traces the final images average."""
        self._photon_noise = self._trace_noise(params)
        score, k_best, state, cache = self._best
        with torch.no_grad():
            for n, p in params.named_parameters():
                p.copy_(state[n])
        self.cache = cache
        self.inputs.log(f"photon level: kept the parameters of refresh {k_best} (image difference {score:.4f} DN)")

    def _trace_noise(self, params):
        """(one trace's photon variance, the images' noise variance), each (3,) in DN^2, at params, from the last
        refresh's averaged cache and its newer trace; (None, None) where the last refresh did not average."""
        if self.cache is None or self.cache.stats.get("averaged_traces", 1) != 2 or self._last_trace is None:
            return None, None
        inp = self.inputs
        mask, intensity = inp.fit_mask.to(inp.device), inp.obs.intensity.to(inp.device)
        with torch.no_grad():
            values = params.values()
            averaged = self.predict(*values)
            kept, self.cache = self.cache, self._last_trace
            newer = self.predict(*values)
            self.cache = kept
        return trace_variance(averaged, newer, mask), image_variance(averaged, intensity, mask)

    def prediction_variance(self):
        """One trace's photon variance (finish's measurement) over the kept cache's traces."""
        single = self._photon_noise[0]
        if single is None or self.cache is None:
            return None
        return single / self.cache.stats.get("averaged_traces", 1)

    def render(self, pd, ps, sigma) -> torch.Tensor:
        """The kept cache's prediction averaged, trace for trace, with caches traced anew at the fitted parameters,
        as many as keep the photon noise small beside the images' own (transport.final_traces): independent
        photons lower the final images' photon noise without widening the density kernels."""
        single, noise = self._photon_noise
        kept_traces = self.cache.stats.get("averaged_traces", 1)
        fresh = fresh_traces(single, noise, kept_traces)
        measured = (
            ""
            if single is None
            else f" (one trace's photon noise {float(single.max()) ** 0.5:.3f} DN against the images' "
            f"{float(noise.min()) ** 0.5:.3f} DN)"
        )
        self.inputs.log(
            f"photon level: the final images average the kept cache ({kept_traces} trace(s)) and {fresh} fresh "
            f"trace(s){measured}"
        )
        images = self.predict(pd, ps, sigma) * kept_traces
        kept = self.cache
        for i in range(1, fresh + 1):
            self.cache = self.refresher.cache(
                pd, ps, sigma, refresh=self.refits + i, progress=self.inputs.cfg.output.progress
            )
            images = images + self.predict(pd, ps, sigma)
        self.cache = kept
        return images / (kept_traces + fresh)

    def report(self) -> dict:
        return {
            "image_difference_per_refresh": self.scores,
            "refresh_at_s": self.refresh_at,
            "pd_change_per_refresh": self.pd_change,
            "pd_std_median_per_refresh": self.pd_std,
            "kept_refresh": self._best[1],
            "smoothing_texels": self.smoothing,
            "specular_smoothing_texels": self.specular_smoothing,
            "cache": self.cache.stats,
        }
