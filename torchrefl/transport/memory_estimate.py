"""Up-front memory estimate of the interreflection levels from the capture's size, and the refusal of a run that would
not fit in the memory the machine has free.

The estimate adds, to what the process holds already (the capture, the observations), the largest arrays each level
builds, from the capture's size: texels T, images P, distinct lights traced, photons per light, patches Q, emitter
maps K. Each term is its arrays' bytes times the copies alive at once (COPIES_*), the constants measured on the
fold (docs/results/performance.md, "Memory"). The check refuses a run whose estimate exceeds the free memory with a
MemoryLimitError naming the setting of the largest term and the value that would fit. The photons' term is checked
again before the first refresh with the stored hits per photon a pilot trace measures (check_photon_memory).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from torchrefl.config import Config
from torchrefl.core.memory import available_mb
from torchrefl.errors import MemoryLimitError
from torchrefl.transport.photon_density import ROW_CHUNK_SLOTS, density_kernels, window_slots

_MB = 2.0**20
#: bytes per (image, texel) of the fit beyond the capture: predictions, residuals, the level's indirect terms, the LM
#: Jacobian columns (7 parameters x 3 channels) and the re-estimation's sigma-search profiles, float32/float64 mixed
FIT_BYTES_PER_OBSERVATION = 400
#: bytes per (image, texel) of a local fit whose per-texel stages run in chunks of texels (torchrefl.fit.texel_chunks):
#: what stays whole, the local terms (36), the predicted images (12) and the refinement's and the render's
#: temporaries over them; a chunk's pairs take FIT_BYTES_PER_OBSERVATION each
CHUNKED_BYTES_PER_OBSERVATION = 120
#: bytes per form-factor ray: the (source, target) patch indices and the weight before merging, kept while sorting
FORM_FACTOR_BYTES_PER_RAY = 48
#: bytes per (image, emitter map, texel): the maps' irradiance, the per-map indirect irradiance and radiance of one
#: radiosity solve (3 float64 channels each)
EMITTER_BYTES = 3 * 3 * 8
#: stored photon hits per photon emitted, assumed up front (second and later bounces; photons leaving the object store
#: none; with the specular gather only those of paths with a specular scattering): 0.056 on the full fold, 0.34 in the
#: bowl (docs/results/performance.md); a pilot trace measures it before the first refresh (check_photon_memory)
HITS_PER_PHOTON = 0.15
#: peak bytes per stored hit while a refresh traces and reduces: the hits' arrays and the bounces' batches they are
#: gathered from at the end of a trace (the reduction runs one light at a time, so its temporaries are a light's)
HIT_PEAK_BYTES = 150
#: specular entries: about 2 per stored hit and image of its light (the photons' and the gather's), at most 16 per
#: (image, texel) once merged into half-angle bins (the fold, one image a light: 11-12.6 M entries for 5.5-5.7 M
#: hits and 20 x 34 449 observations; a 313 808-texel bowl, 40 images of 6 lights: 44.7 M for 3.4 M hits, 13 a hit;
#: the tiny fold 0.05 per hit); each takes ENTRY_BYTES in every cache alive (int64 observation, float32 theta_h and 3
#: weights); the cache average merges them one light at a time (a light's temporaries)
ENTRIES_PER_HIT, ENTRIES_PER_OBSERVATION, ENTRY_BYTES = 2, 16, 24
#: bytes per window slot (texel x window offset, photon_density.window_slots) of the density kernels while they are
#: built: the smoother keeps 12 a slot it fills and builds ROW_CHUNK_SLOTS of them at a time (about 24 a slot of the
#: chunk beside them); the spread's copies and their sort take 68 (it keeps 14); measured on a 300 x 300 grid
SMOOTHER_BYTES_PER_SLOT, SMOOTHER_CHUNK_BYTES_PER_SLOT, SPREAD_BYTES_PER_SLOT = 14, 24, 68
#: caches alive at the peak: the previous trace, the cache the fit used (the best, usually), the new trace, and
#: their average
CACHES_ALIVE = 4


@dataclass(frozen=True)
class MemoryEstimate:
    """Estimated MiB a run adds to what the process holds: per named term, each with the config key that lowers it."""

    terms: dict[str, float] = field(default_factory=dict)  # term -> MiB
    settings: dict[str, str] = field(default_factory=dict)  # term -> the config key that brings it down

    @property
    def total_mb(self) -> float:
        return float(sum(self.terms.values()))

    def largest(self) -> str:
        return max(self.terms, key=self.terms.get)


def estimate_memory(
    cfg: Config,
    texels: int,
    images: int,
    level: str,
    lights_traced: int | None = None,
    maps_per_light: int = 1,
    patches: int | None = None,
    chunk_pairs: int | None = None,
) -> MemoryEstimate:
    """The MiB the fit at `level` ('local', 'radiosity', 'photon') adds for a capture of `texels` texels and `images`
    images (lights_traced: distinct lights the photons are traced for, default `images`; maps_per_light: emitter and
    photon maps per light for lights that move with the scan; patches: radiosity patches, default texels /
    patch_size^2; chunk_pairs: the (image, texel) pairs of the largest chunk where the local fit runs in chunks of
    texels, None where it does not)."""
    if chunk_pairs is None:
        terms = {"fit": images * texels * FIT_BYTES_PER_OBSERVATION / _MB}
    else:
        terms = {
            "fit": (images * texels * CHUNKED_BYTES_PER_OBSERVATION + chunk_pairs * FIT_BYTES_PER_OBSERVATION) / _MB
        }
    settings = {"fit": "selection.num_lights (fewer images) or the scan's texels (synthetic.columns, rows)"}
    if level in ("radiosity", "photon"):
        rc = cfg.radiosity
        q = patches if patches is not None else math.ceil(texels / rc.patch_size**2)
        rays = q * (rc.hemisphere_samples + (rc.solve_samples or 0))
        terms["form factors"] = rays * FORM_FACTOR_BYTES_PER_RAY / _MB
        settings["form factors"] = "radiosity.hemisphere_samples"
        k = min(maps_per_light, rc.light_maps)
        if k > 1:
            terms["emitter maps"] = images * k * texels * EMITTER_BYTES / _MB
            settings["emitter maps"] = "radiosity.light_maps"
    if level == "photon":
        traced = images if lights_traced is None else lights_traced
        terms["photons"] = photons_mb(cfg.photon.photons_per_light * traced, images, texels, lights=traced)
        settings["photons"] = "photon.photons_per_light"
        terms["density kernels"] = kernels_mb(cfg, texels)
        settings["density kernels"] = (
            "photon.smoothing and photon.specular_smoothing (texels; null: automatic, narrower with more "
            "photon.photons_per_light)"
        )
    return MemoryEstimate(terms, settings)


def kernels_mb(cfg: Config, texels: int) -> float:
    """The MiB the photon level's density kernels (photon_density.smoothing_matrix and SpreadKernel, built once at the
    first refresh) take while they are built, at the config's kernel widths for `texels` texels."""
    pc = cfg.photon
    smoother, spread = window_slots(*density_kernels(pc.photons_per_light, texels, pc.smoothing, pc.specular_smoothing))
    chunk = min(texels * smoother, ROW_CHUNK_SLOTS) * SMOOTHER_CHUNK_BYTES_PER_SLOT
    return (texels * (smoother * SMOOTHER_BYTES_PER_SLOT + spread * SPREAD_BYTES_PER_SLOT) + chunk) / _MB


def photons_mb(
    photons: float, images: int, texels: int, hits_per_photon: float = HITS_PER_PHOTON, lights: int | None = None
) -> float:
    """The MiB a photon refresh of `photons` photons (all `lights` distinct lights traced; default one per image) adds
    at its peak, with its caches alive, for `images` images of `texels` texels, at `hits_per_photon` stored hits per
    photon."""
    hits = photons * hits_per_photon
    irradiance = images * texels * 3 * 4
    # a hit has specular entries in each image of its light
    per_light = images / max(1, lights if lights is not None else images)
    entries = min(hits * ENTRIES_PER_HIT * per_light, images * texels * ENTRIES_PER_OBSERVATION)
    return (hits * HIT_PEAK_BYTES + CACHES_ALIVE * (entries * ENTRY_BYTES + irradiance)) / _MB


def check_photon_memory(
    hits_per_photon: float, photons: int, images: int, texels: int, log, lights: int | None = None
) -> float:
    """Before the first photon refresh: the photons' term again with the stored hits per photon a pilot trace
    measured (the up-front estimate assumes HITS_PER_PHOTON, which a closed, bright or glossy object exceeds); logs
    it and refuses the run (MemoryLimitError) when it exceeds the free memory. Returns the term's MiB."""
    term = photons_mb(photons, images, texels, hits_per_photon, lights)
    free = free_mb()
    log(
        f"memory: a pilot trace stored {hits_per_photon:.3f} hits per photon (the up-front estimate assumed "
        f"{HITS_PER_PHOTON:g}): the photon refreshes add about {term:.0f} MiB; "
        + (f"{free:.0f} MiB free" if free is not None else "free memory unknown")
    )
    estimate = MemoryEstimate({"photons": term}, {"photons": "photon.photons_per_light"})
    check_memory(estimate, free, f"the photon level at {hits_per_photon:.3f} stored hits per photon")
    return term


def cgroup_free_mb() -> float | None:
    """What the process's cgroup (v2) still allows, in MiB; None without a limit."""
    root = Path("/sys/fs/cgroup")
    try:
        limit = (root / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return (int(limit) - int((root / "memory.current").read_text())) / _MB
    except (OSError, ValueError):
        return None


def free_mb() -> float | None:
    """The memory a run can still take: the machine's available memory, within the cgroup's limit; None unknown."""
    known = [v for v in (available_mb(), cgroup_free_mb()) if v is not None]
    return min(known) if known else None


def check_memory(estimate: MemoryEstimate, free: float | None, what: str) -> None:
    """Refuse (MemoryLimitError) an estimate above the free MiB (None: unknown, not checked), naming the largest term's
    setting and the share of it that would fit. what: the run, for the message."""
    if free is None or estimate.total_mb <= free:
        return
    big = estimate.largest()
    others = estimate.total_mb - estimate.terms[big]
    share = max(0.0, (free - others) / estimate.terms[big])
    parts = ", ".join(f"{name} {mb:.0f}" for name, mb in sorted(estimate.terms.items(), key=lambda t: -t[1]))
    raise MemoryLimitError(
        f"{what} would need about {estimate.total_mb:.0f} MiB more ({parts} MiB) and the machine has {free:.0f} MiB "
        f"free: lower {estimate.settings[big]} "
        + (f"to about {share:.0%} of its value" if share > 0 else "(the other terms alone exceed the free memory)")
        + " or free memory"
    )


def check_level_memory(level) -> MemoryEstimate:
    """Estimate the memory a prepared-to-be TransportLevel will add for its capture, log it, and refuse the run
    (MemoryLimitError) when it exceeds the free memory."""
    from torchrefl.transport.light_maps import light_sources
    from torchrefl.transport.photon_refresh import distinct_lights

    inp = level.inputs
    cfg, surface, obs = inp.cfg, inp.surface, inp.obs
    maps, traced = 1, obs.num_lights
    if level.name in ("radiosity", "photon") and surface.has_mesh:
        sources = light_sources(surface, obs, max(cfg.radiosity.light_maps, cfg.photon.light_maps))
        maps, traced = sources.num_maps, len(distinct_lights(sources)[0])
    chunks = inp.chunks if level.name == "local" else None
    pairs = None if chunks is None else max(c.pairs for c in chunks)
    estimate = estimate_memory(cfg, surface.num_texels, obs.num_lights, level.name, traced, maps, chunk_pairs=pairs)
    free = free_mb()
    parts = ", ".join(f"{name} {mb:.0f}" for name, mb in estimate.terms.items())
    inp.log(
        f"memory: the {level.name} level's fit estimated at {estimate.total_mb:.0f} MiB more ({parts} MiB); "
        + (f"{free:.0f} MiB free" if free is not None else "free memory unknown")
    )
    check_memory(estimate, free, f"fit.model {cfg.fit.model} (the {level.name} level) on {surface.num_texels} texels")
    return estimate
