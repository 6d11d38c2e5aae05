"""Global search over sigma by variable projection (an initialiser beyond the seed's closed forms).

For a fixed sigma the local model i = Pd A + Ps D(theta_h; sigma) B is linear in Pd and Ps, so
the least-squares Pd and Ps follow in closed form, and so does the remaining squared error.
Evaluating that error on a geometric grid of sigma values finds the global minimum over sigma
(per texel, or for one lobe shared by the whole object) without any local-minimum trap; the
autograd refinement then polishes from there.

The interreflection levels add indirect light that is linear in the texel's own Pd and Ps for fixed sigma
(Method III's cache: kappa (Pd/pi H + Ps S(sigma))): transport.levels.base.IndirectTerms adds those factors
to A and E, so the same search re-estimates every texel against direct plus cached indirect light.

Per group g (a texel-channel, a texel, or the whole object), with sums over fitted observations:
    u = i - A S_Ai / S_AA,  v = E - A S_AE / S_AA   (E = D B; Pd eliminated per texel and channel)
    Ps = clamp(sum(u v) / sum(v v), 0, ps_max),  error = sum(u u) - 2 Ps sum(u v) + Ps^2 sum(v v)
    Pd = (S_Ai - Ps S_AE) / S_AA.
"""

from __future__ import annotations

import math
from typing import Optional

import torch

from torchrefl.core.brdf import specular_lobe
from torchrefl.transport.levels.base import IndirectTerms
from torchrefl.transport.local import LocalTerms


def sigma_grid(sigma_min: float, sigma_max: float, count: int) -> torch.Tensor:
    """(count,) geometric grid between the bounds."""
    return torch.exp(torch.linspace(math.log(sigma_min), math.log(sigma_max), count, dtype=torch.float64))


def profile_search(
    terms: LocalTerms,
    intensity: torch.Tensor,
    mask: torch.Tensor,
    sigmas: torch.Tensor,
    ps_channels: int = 3,
    shared: bool = False,
    ps_max: float = float("inf"),
    indirect: Optional[IndirectTerms] = None,
):
    """Best (pd (T, 3), ps (T, C), sigma (T,), error (T,)) over the sigma grid.

    intensity (P, T, 3); mask (P, T) fitted observations. shared=True picks one sigma and one Ps
    for all texels (Pd stays per texel). indirect: cached interreflection added to the local model.
    """
    dt = intensity.dtype
    w = mask.to(dt)[..., None]
    A = (terms.diffuse if indirect is None else terms.diffuse + indirect.diffuse.to(dt)) * w
    i = intensity * w
    S_AA = (A * A).sum(0).clamp_min(1e-30)  # (T, 3)
    S_Ai = (A * i).sum(0)
    S_ii = (i * i).sum(0)
    uu = S_ii - S_Ai * S_Ai / S_AA
    best = None
    for s in sigmas.tolist():
        E = specular_lobe(terms.brdf, terms.theta_h, torch.tensor(s, dtype=dt))[..., None] * terms.specular
        if indirect is not None:
            E = E + indirect.specular(s).to(dt)
        E = E * w
        S_AE = (A * E).sum(0)
        uv = (E * i).sum(0) - S_AE * S_Ai / S_AA
        vv = ((E * E).sum(0) - S_AE * S_AE / S_AA).clamp_min(0)
        if shared:
            red = lambda x: x.sum(0, keepdim=True)  # (1, 3)
        else:
            red = lambda x: x  # (T, 3)
        g_uv, g_vv = red(uv), red(vv)
        if ps_channels == 1:
            g_uv, g_vv = g_uv.sum(-1, keepdim=True), g_vv.sum(-1, keepdim=True)
        ps = (g_uv / g_vv.clamp_min(1e-30)).clamp(0, ps_max)
        ps = torch.where(g_vv > 0, ps, torch.zeros_like(ps))
        ps_full = ps.expand(uv.shape[0], 3) if ps.shape[-1] == 1 or shared else ps
        ps_full = ps_full.expand(uv.shape[0], 3)
        err = (uu - 2 * ps_full * uv + ps_full * ps_full * vv).sum(-1)  # (T,)
        pd = ((S_Ai - ps_full * S_AE) / S_AA).clamp_min(0)
        sig = torch.full((uv.shape[0],), s, dtype=dt)
        ps_out = ps.expand(uv.shape[0], ps.shape[-1]).clone()
        if best is None:
            best = [pd, ps_out, sig, err]
            continue
        if shared:
            if float(err.sum()) < float(best[3].sum()):
                best = [pd, ps_out, sig, err]
        else:
            better = err < best[3]
            best[0] = torch.where(better[:, None], pd, best[0])
            best[1] = torch.where(better[:, None], ps_out, best[1])
            best[2] = torch.where(better, sig, best[2])
            best[3] = torch.where(better, err, best[3])
    return tuple(best)
