"""Initial texel parameters for the local fit (Method I, dissertation 3.2).

1. Closed forms: Pd by eq. 3.3, Ps and sigma by eq. 3.5 (torchrefl.fit.closed_form).
2. Optional variable-projection search over sigma (torchrefl.fit.profile_search) at texels with
   specular evidence (at least two T_spec observations): it replaces the closed form where its
   squared error is lower (noise or a rough lobe can defeat the two-observation closed form).
   With fit.specular = shared (or pooled) one lobe for the whole object is searched too.
3. A measured lobe far from its measured neighbours' takes theirs where its error grows by no more than their own
   fits leave (torchrefl.fit.lobe_consensus).
4. Texels whose Ps and sigma are still undetermined take the lobe of the nearest measured texels of their
   diffuse colour (torchrefl.fit.material_fill), or where no measured texel has their colour, of the
   measured texels in their W x W window (torchrefl.fit.interpolate); the fit keeps them near these values
   with a prior, because their own observations carry (almost) no specular signal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch

from torchrefl.core.surface import Surface
from torchrefl.fit.closed_form import closed_form
from torchrefl.fit.interpolate import FILL_MEDIAN, fill_undetermined
from torchrefl.fit.lobe_consensus import settle_outliers
from torchrefl.fit.material_fill import colour_matched_lobes
from torchrefl.fit.profile_search import profile_search, profiled_fit, sigma_grid
from torchrefl.transport.local import LocalTerms, predict

#: coverage codes (params.npz `coverage`, docs/outputs.md): none; Pd with Ps/sigma from measured texels of its colour or
#: interpolated from neighbours;
#: Pd with Ps/sigma measured (the texel's own T_spec observations); Pd from its upper bound only (Ps/sigma
#: interpolated); untrusted geometry (edges, creases, mixed footprints, unfit range: not fitted); Pd with the
#: object's lobe (the shared one, or the measured texels' median lobe far from every measured texel)
#: and misfit (the fitted model cannot explain its observations: torchrefl.fit.misfit; no estimate); Pd with its
#: material's lobe fitted to the material's interreflected light (torchrefl.fit.material_lobe)
COVER_NONE, COVER_PD_ONLY, COVER_FULL, COVER_PD_BOUND, COVER_UNTRUSTED, COVER_SHARED, COVER_MISFIT = range(7)
COVER_MATERIAL = 7


@dataclass
class Initial:
    """pd (T, 3), ps (T, C), sigma (T,) starting values; known (T,) Ps/sigma determined from the
    texel's own data; defined (T,) any fitted observation; coverage (T,) int8 code; shared_lobe
    (ps (1, C), sigma (1,)) or None; note: a line for the log."""

    pd: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    known: torch.Tensor
    defined: torch.Tensor
    coverage: torch.Tensor
    pd_from_diffuse: torch.Tensor
    spec_closed_form: torch.Tensor
    shared_lobe: Optional[tuple]
    note: str


@dataclass
class TexelLobes:
    """The per-texel part of the start: the closed forms and, with the search, each texel's own sigma search result
    where it fits better (Pd (T, 3), Ps (T, C), sigma (T,); known (T,) the lobe from the texel's own data; error (T,)
    the squared error of its fitted observations with it, None without the search; taken: texels the search set)."""

    pd: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    known: torch.Tensor
    error: Optional[torch.Tensor]
    taken: torch.Tensor
    defined: torch.Tensor
    pd_from_diffuse: torch.Tensor
    spec_closed_form: torch.Tensor


def texel_lobes(
    terms: LocalTerms,
    intensity: torch.Tensor,
    cls: torch.Tensor,
    n_spec: torch.Tensor,
    fit_mask: torch.Tensor,
    *,
    ps_channels: int,
    sigma_min: float,
    sigma_max: float,
    ps_max: float,
    sigma_search: int,
) -> TexelLobes:
    """Closed forms and (sigma_search > 0) each texel's sigma search where it has specular evidence (two or more
    T_spec observations) and the search fits better: texel by texel, a texel's result its own observations' only."""
    cf = closed_form(terms, intensity, cls, fit_mask, ps_channels, sigma_min, sigma_max)
    defined = cf.pd_defined
    pd, ps, sigma = cf.pd.clone(), cf.ps.clamp(0, ps_max), cf.sigma.clone()
    known, error, take = cf.spec_determined.clone(), None, torch.zeros_like(defined)
    if sigma_search > 0 and terms.brdf != "lambertian":
        evidence = (n_spec >= 2) & defined
        grid = sigma_grid(sigma_min, sigma_max, sigma_search)
        pd_s, ps_s, sg_s, err_s = _searched(terms, intensity, fit_mask, evidence, grid, ps_channels, ps_max)
        with torch.no_grad():
            r0 = (predict(terms, cf.pd, ps, sigma) - intensity) * fit_mask[..., None]
            err0 = (r0 * r0).sum((0, 2))
        take = evidence & (~cf.spec_determined | (err_s < err0))
        pd = torch.where(take[:, None], pd_s.to(pd.dtype), pd)
        ps = torch.where(take[:, None], ps_s.to(ps.dtype), ps)
        sigma = torch.where(take, sg_s.to(sigma.dtype), sigma)
        known = cf.spec_determined | take
        error = torch.where(take, err_s.to(err0.dtype), err0)
    return TexelLobes(pd, ps, sigma, known, error, take, defined, cf.pd_from_diffuse, cf.spec_determined)


def _searched(terms: LocalTerms, intensity, fit_mask, evidence, grid, ps_channels: int, ps_max: float):
    """profile_search's (pd, ps, sigma, error) over all texels, searched at the texels with evidence (T,) only, each
    under the images with a fitted observation of any of them (the others are 0 and infinitely wrong): a texel's
    search reads its own observations only, and on a large mesh_views capture most texels lack specular evidence
    and most (image, texel) pairs are no observation."""
    T = int(evidence.shape[0])
    texels = evidence.nonzero()[:, 0]
    images = fit_mask.index_select(1, texels).any(1).nonzero()[:, 0]
    dt = intensity.dtype
    pd, ps = (
        torch.zeros(T, 3, dtype=dt, device=intensity.device),
        torch.zeros(T, ps_channels, dtype=dt, device=intensity.device),
    )
    sigma, err = (
        torch.ones(T, dtype=dt, device=intensity.device),
        torch.full((T,), float("inf"), dtype=dt, device=intensity.device),
    )
    if not len(texels) or not len(images):
        return pd, ps, sigma, err
    pick = lambda x: x.index_select(1, texels).index_select(0, images)  # noqa: E731
    found = profile_search(
        terms.subset(texels, images), pick(intensity), pick(fit_mask), grid, ps_channels, ps_max=ps_max
    )
    return tuple(full.index_copy(0, texels, part.to(full.dtype)) for full, part in zip((pd, ps, sigma, err), found))


def initialise_local(
    terms: LocalTerms,
    intensity: torch.Tensor,
    cls: torch.Tensor,
    n_spec: torch.Tensor,
    fit_mask: torch.Tensor,
    surface: Surface,
    *,
    ps_channels: int,
    sigma_min: float,
    sigma_max: float,
    ps_max: float,
    window: int,
    sigma_search: int,
    specular: str,
    chunks: Optional[list] = None,
) -> Initial:
    """Closed forms, sigma search and interpolation; see the module docstring. chunks: the per-texel stages (the
    closed forms, the sigma search, the lobe consensus's evaluations) run chunk by chunk on the texels and images
    of each (torchrefl.fit.texel_chunks; with fit.specular texel only); None: on all at once."""
    search = sigma_search > 0 and terms.brdf != "lambertian"
    options = dict(ps_channels=ps_channels, sigma_min=sigma_min, sigma_max=sigma_max, ps_max=ps_max)
    per_texel = sigma_search if specular != "shared" else 0
    if chunks is None:
        lobes = texel_lobes(terms, intensity, cls, n_spec, fit_mask, sigma_search=per_texel, **options)
    else:
        from torchrefl.fit.texel_chunks import chunked_lobes

        lobes = chunked_lobes(chunks, terms, intensity, cls, n_spec, fit_mask, sigma_search=per_texel, **options)
    pd, ps, sigma, known, defined = lobes.pd, lobes.ps, lobes.sigma, lobes.known, lobes.defined
    shared_lobe = None
    note = "sigma search off"
    if search and specular in ("shared", "pooled"):
        grid = sigma_grid(sigma_min, sigma_max, sigma_search)
        pd_g, ps_g, sg_g, _ = profile_search(terms, intensity, fit_mask, grid, ps_channels, shared=True, ps_max=ps_max)
        shared_lobe = (ps_g[:1].to(ps.dtype), sg_g[:1].to(sigma.dtype))
    if search and specular == "shared":
        pd, ps, sigma = pd_g.to(pd.dtype), ps_g.to(ps.dtype), sg_g.to(sigma.dtype)
        known = defined.clone()
        note = f"one shared lobe: Ps {[round(float(x), 4) for x in ps_g[0]]}, sigma {float(sg_g[0]):.4f}"
    elif search:
        if chunks is None:
            profile = profiled_fit(terms, intensity, fit_mask, ps_channels, ps_max)
        else:
            from torchrefl.fit.texel_chunks import chunked_profile

            profile = chunked_profile(chunks, terms, intensity, fit_mask, ps_channels, ps_max)
        pd, ps, sigma, adopt = settle_outliers(surface, pd, ps, sigma, lobes.error, known & defined, window, profile)
        note = f"sigma search kept at {int(lobes.taken.sum())} texels with specular evidence"
        note += f", {int(adopt.sum())} took their measured neighbours' lobe"
        if shared_lobe is not None:
            note += f"; shared lobe Ps {[round(float(x), 4) for x in shared_lobe[0][0]]}, "
            note += f"sigma {float(shared_lobe[1][0]):.4f}"
    ps, sigma, object_lobe, matched = fill_lobes(
        surface, pd, ps, sigma, known, defined, n_spec, window, sigma_min, sigma_max
    )
    ps = ps.clamp(0, ps_max)
    sigma = sigma.clamp(sigma_min, sigma_max)
    coverage = _start_coverage(surface.num_texels, defined, lobes.pd_from_diffuse, object_lobe, known, specular)
    head = (
        f"closed form: Pd from eq. 3.3 at {int(lobes.pd_from_diffuse.sum())} texels, bound at "
        f"{int((defined & ~lobes.pd_from_diffuse).sum())}, Ps/sigma from eq. 3.5 at "
        f"{int(lobes.spec_closed_form.sum())}; "
        f"Ps/sigma known at {int((known & defined).sum())} of {surface.num_texels} texels, the rest taken from "
        f"measured texels of their colour ({int((matched & defined).sum())}), interpolated (W = {window}) or, beyond "
        f"two windows, the measured texels' median lobe ({int((object_lobe & defined).sum())}); {note}"
    )
    return Initial(
        pd,
        ps,
        sigma,
        known & defined,
        defined,
        coverage,
        lobes.pd_from_diffuse,
        lobes.spec_closed_form,
        shared_lobe,
        head,
    )


def _start_coverage(T: int, defined, pd_from_diffuse, object_lobe, known, specular: str) -> torch.Tensor:
    """(T,) int8 coverage code of each texel at the start (the COVER_ codes above): none where nothing was fitted, else
    Pd only, Pd bound (not from the diffuse closed form), the object's lobe, or its own lobe (the shared one with
    fit.specular shared)."""
    coverage = torch.full((T,), COVER_NONE, dtype=torch.int8)
    coverage[defined] = COVER_PD_ONLY
    coverage[defined & ~pd_from_diffuse] = COVER_PD_BOUND
    coverage[object_lobe & defined] = COVER_SHARED
    coverage[known & defined] = COVER_SHARED if specular == "shared" else COVER_FULL
    return coverage


def mark_untrusted(coverage: torch.Tensor, untrusted: torch.Tensor | None) -> torch.Tensor:
    """coverage (T,) int8 with COVER_UNTRUSTED at the texels without an estimate that the capture left unfitted
    for their geometry (untrusted (T,) bool: Capture.untrusted; None: none)."""
    if untrusted is None:
        return coverage
    out = coverage.clone()
    out[untrusted.to(torch.bool) & (coverage == COVER_NONE)] = COVER_UNTRUSTED
    return out


def fill_lobes(
    surface: Surface, pd, ps, sigma, known, defined, n_spec, window: int, sigma_min: float, sigma_max: float
):
    """Ps (T, C), sigma (T,) with the texels not `known` filled from measured texels of their colour
    (torchrefl.fit.material_fill) or else their window (torchrefl.fit.interpolate), and (T,) bool: the texels that
    took the measured texels' median lobe. Without any known texel: a faint mid-range lobe."""
    if not known.any():
        none = torch.zeros(surface.num_texels, dtype=torch.bool)
        return torch.full_like(ps, 1e-3), torch.full_like(sigma, 0.5 * (sigma_min + sigma_max)), none, none
    values = torch.cat([ps, sigma[:, None]], 1).double()
    filled, how = fill_undetermined(surface.neighbours, values, known, defined, window=window)
    flat = filled.to(ps.dtype)
    ps = torch.where(known[:, None], ps, flat[:, :-1])
    sigma = torch.where(known, sigma, flat[:, -1])
    ps, sigma, matched = colour_matched_lobes(surface.positions, pd, ps, sigma, known, defined & ~known, n_spec)
    return ps, sigma, (how == FILL_MEDIAN) & ~known & ~matched, matched
