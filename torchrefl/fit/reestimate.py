"""Re-estimation against the level's indirect light before each refit of an interreflection level.

The closed-form start and its sigma search (torchrefl.fit.initialise) see the intensities with only
the diffuse interreflection removed (Method II's start); the joint refinement then has to walk every
texel's Ps-sigma valley from there, and 60 LBFGS steps over all texels at once do not get there where
the specular interreflection is strong (the non-uniform glossy fold: per-texel Ps 7-20 % low; started
at the truth the same fit stays within 2-3 %). Before each refit the sigma search runs again, per texel,
on the local model plus the level's indirect light held at the current parameters
(TransportLevel.indirect_terms), and texels with specular evidence restart from its result where it
fits their observations better; a measured lobe far from its measured neighbours' takes theirs where its error grows by
no more than their own fits leave (torchrefl.fit.lobe_consensus). Then the texels without specular evidence take the
lobes of the measured texels of their colour again (`lend_lobes`, torchrefl.fit.material_fill): at the start those
were measured without the interreflection (on the fold, region 0's lenders had Ps 0.01-0.04 against 0.39). The
texels of a colour no measured texel has take one lobe per material fitted to the light they reflect off the
object (`material_lobes`, torchrefl.fit.material_lobe) instead of the object's median lobe.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch

from torchrefl.config import Config
from torchrefl.core.observation_classes import T_SPEC
from torchrefl.core.params import TexelParams
from torchrefl.fit.lobe_consensus import settle_outliers
from torchrefl.fit.material_fill import colour_matched_lobes
from torchrefl.fit.material_lobe import cluster_lobes, colour_clusters
from torchrefl.fit.outer_skip import IndirectMemory
from torchrefl.fit.profile_search import profile_search, profiled_fit, sigma_grid
from torchrefl.transport.levels.base import IndirectTerms, TransportLevel


@dataclass
class Reestimated:
    """restarted: texels restarted from the search; lent: (T,) bool texels without specular evidence that took the
    lobe of measured texels of their colour; pooled: (T,) bool texels that took their material's lobe fitted to its
    interreflected light (torchrefl.fit.material_lobe) (None: none)."""

    restarted: int = 0
    lent: Optional[torch.Tensor] = None
    pooled: Optional[torch.Tensor] = None
    searched: int = 0
    memory: Optional[IndirectMemory] = None


def reestimate(
    level: TransportLevel, params: TexelParams, cfg: Config, memory: Optional[IndirectMemory] = None
) -> Reestimated:
    """Restart the texels with at least two fitted T_spec observations from the sigma search against direct plus
    the level's indirect light where that lowers their squared error, then lend the measured lobes to the texels
    without specular evidence (lend_lobes). memory: the indirect terms the last re-estimation saw (its result's
    `memory`; None: none): the search runs only on the texels whose indirect light moved by more than
    fit.noise_floor_dn since (torchrefl.fit.outer_skip); searched: how many it ran on."""
    inp, rc, fc = level.inputs, cfg.reflectance, cfg.fit
    if params.shared_specular or fc.sigma_search <= 0 or inp.terms.brdf == "lambertian":
        return Reestimated()
    with torch.no_grad():
        pd, ps, sigma = (x.detach() for x in params.values())
        terms = level.indirect_terms(pd)
        if terms is None:
            return Reestimated()
        cpu = _on_cpu(terms)
        intensity, mask = inp.obs.intensity, inp.fit_mask
        evidence = ((inp.classes == T_SPEC) & mask).sum(0) >= 2
        search = evidence
        if memory is not None:
            search = evidence & memory.changed(cpu, pd.cpu(), ps.cpu(), mask, fc.noise_floor_dn)
        grid = sigma_grid(rc.sigma_min, rc.sigma_max, fc.sigma_search)
        residual = (level.predict(pd, ps, sigma).cpu() - intensity) * mask[..., None]
        err0 = residual.square().sum((0, 2))
        pd_s, ps_s, sg_s = pd.cpu().clone(), ps.cpu().clone(), sigma.cpu().clone()
        err_s = torch.full_like(err0, float("inf"))
        index = search.nonzero()[:, 0]
        if len(index):  # only these texels can restart: the search runs on them alone
            found = profile_search(
                inp.terms.texels(index),
                intensity.index_select(1, index),
                mask.index_select(1, index),
                grid,
                rc.ps_channels,
                ps_max=rc.ps_max,
                indirect=cpu.texels(index),
            )
            for full, part in zip((pd_s, ps_s, sg_s, err_s), found):
                full[index] = part.to(full.dtype)
        take = search & (err_s < err0)
        pd_new = torch.where(take[:, None], pd_s.to(pd.dtype), pd.cpu())
        ps_new = torch.where(take[:, None], ps_s.to(ps.dtype), ps.cpu())
        sigma_new = torch.where(take, sg_s.to(sigma.dtype), sigma.cpu())
        error = torch.where(take, err_s.to(err0.dtype), err0)
        profile = profiled_fit(inp.terms, intensity, mask, rc.ps_channels, ps_max=rc.ps_max, indirect=cpu)
        window = fc.interpolation_window
        pd_new, ps_new, sigma_new, adopt = settle_outliers(
            inp.surface, pd_new, ps_new, sigma_new, error, evidence, window, profile
        )
        take = take | adopt
        if bool(take.any()):
            dev = params.raw_pd.device
            params.assign(pd_new.to(dev), ps_new.to(dev), sigma_new.to(dev))
    lent = lend_lobes(level, params)
    pooled = material_lobes(level, params, cpu, evidence if lent is None else evidence | lent, cfg)
    return Reestimated(int(take.sum()), lent, pooled, len(index), IndirectMemory.of(cpu, sigma.cpu()))


def _on_cpu(terms: IndirectTerms) -> IndirectTerms:
    """The indirect terms with every factor they give moved to the CPU (the re-estimation's sums run there)."""
    of = terms.specular_of
    return IndirectTerms(
        terms.diffuse.cpu(),
        lambda s: terms.specular(s).cpu(),
        None if of is None else (lambda texels: lambda s, f=of(texels): f(s).cpu()),
    )


def material_lobes(
    level: TransportLevel, params: TexelParams, indirect: IndirectTerms, done: torch.Tensor, cfg: Config
) -> torch.Tensor | None:
    """Set the lobe of the fitted texels not in done (T,) bool (measured or lent) to their colour cluster's lobe
    fitted with the level's indirect light (torchrefl.fit.material_lobe); returns the (T,) bool texels so set, or
    None where none was."""
    inp, rc = level.inputs, cfg.reflectance
    with torch.no_grad():
        pd, ps, sigma = (x.detach().cpu() for x in params.values())
        members = inp.fit_mask.any(0) & ~done.cpu()
        cluster = colour_clusters(inp.surface.neighbours, pd, members)
        if cluster.max() < 0:
            return None
        cluster = torch.from_numpy(cluster)
        index = (cluster >= 0).nonzero()[:, 0]  # the lobes are fitted to the clusters' texels alone
        profile = profiled_fit(
            inp.terms.texels(index),
            inp.obs.intensity.index_select(1, index),
            inp.fit_mask.index_select(1, index),
            rc.ps_channels,
            rc.ps_max,
            indirect.texels(index),
        )
        grid = sigma_grid(rc.sigma_min, rc.sigma_max, max(3, 2 * cfg.fit.sigma_search))
        ps_c, sg_c, determined = cluster_lobes(profile.parts, cluster[index].numpy(), grid, rc.ps_channels, rc.ps_max)
        pooled = (cluster >= 0) & determined[cluster.clamp_min(0)]
        if not bool(pooled.any()):
            return None
        of = cluster[pooled]
        ps, sigma = ps.clone(), sigma.clone()
        ps[pooled] = ps_c[of].to(ps.dtype)
        sigma[pooled] = sg_c[of].to(sigma.dtype)
        dev = params.raw_pd.device
        params.assign(pd.to(dev), ps.to(dev), sigma.to(dev))
    sizes = torch.bincount(of, minlength=len(sg_c))
    lobes = ", ".join(
        f"{int(n)} texels Ps {float(p.mean()):.3f} sigma {float(g):.3f}"
        for n, p, g, d in zip(sizes, ps_c, sg_c, determined)
        if d
    )
    inp.log(
        f"{int(determined.sum())} materials without highlights, lobes fitted to their interreflected light: {lobes}"
    )
    return pooled


def lend_lobes(level: TransportLevel, params: TexelParams) -> torch.Tensor | None:
    """Set the lobe of every fitted texel with fewer than two fitted T_spec observations that has measured texels of its
    colour to theirs (torchrefl.fit.material_fill, from the current lobes); returns the (T,) bool texels so set, or
    None where none was."""
    inp = level.inputs
    with torch.no_grad():
        highlights = ((inp.classes == T_SPEC) & inp.fit_mask).sum(0)
        evidence = highlights >= 2
        fitted = inp.fit_mask.any(0)
        pd, ps, sigma = (x.detach().cpu() for x in params.values())
        ps, sigma, lent = colour_matched_lobes(
            inp.surface.positions, pd, ps, sigma, evidence, fitted & ~evidence, highlights
        )
        if not bool(lent.any()):
            return None
        dev = params.raw_pd.device
        params.assign(pd.to(dev), ps.to(dev), sigma.to(dev))
    return lent
