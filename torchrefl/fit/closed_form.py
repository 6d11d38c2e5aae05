"""Closed-form initial estimates (Method I, dissertation 3.2).

Written on the precomputed local terms i = Pd * A + Ps * D(theta_h; sigma) * B
(torchrefl.transport.local.LocalTerms), which generalises the seed's Y/C^2 factors
to any kappa, light intensity and falloff.

- Pd (eq. 3.3): Pd = i / A, least squares over the T_diff observations (see closed_form_pd).
  Texels with no T_diff observation get an upper bound of Pd and are flagged.
- Ps, sigma (eq. 3.4-3.5): the specular part a_k = (i_k - Pd A_k) / B_k = Ps D(theta_k; sigma)
  of the T_spec observations. D is exp(-x / (c sigma^2)) up to a sigma-only factor, with
  x = theta_h^2, c = 2 (Torrance-Sparrow) or x = tan^2 theta_h, c = 1 (Ward), so
  ln a_k = ln(Ps K(sigma)) - x_k / (c sigma^2) is a line in x_k. With exactly two
  observations this is the seed's pair of equations (3.5); with more, a weighted least-squares
  line through all of them (weights i_s^2, the inverse variance of ln a_k), which uses the
  same physics with less noise. A texel is determined when at least two T_spec observations
  carry specular signal above `min_specular` and span a range of x; otherwise it is left
  for interpolation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from torchrefl.core.brdf import specular_lobe
from torchrefl.core.observation_classes import T_DIFF, T_SPEC
from torchrefl.transport.local import LocalTerms


@dataclass
class ClosedForm:
    """pd (T, 3); ps (T, C); sigma (T,); pd_from_diffuse (T,) bool (eq. 3.3 used, else the bound);
    spec_determined (T,) bool (eq. 3.5 solved); pd_defined (T,) bool (any valid observation)."""

    pd: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    pd_from_diffuse: torch.Tensor
    pd_defined: torch.Tensor
    spec_determined: torch.Tensor


def closed_form_pd(
    terms: LocalTerms, intensity: torch.Tensor, cls: torch.Tensor, usable: torch.Tensor, min_signal: float = 8.0 / 255.0
):
    """Eq. 3.3 over the T_diff observations. intensity (P, T, 3), cls (P, T), usable (P, T).

    With one T_diff observation this is the seed's Pd = C^2 i / (Y cos theta_d); with several it is
    their least-squares combination Pd = sum(A i) / sum(A^2), which weights bright (reliable)
    observations most: the seed's "smallest theta_h above theta_th1" is often a grazing, nearly
    black observation where 8-bit quantisation dominates. Texels without a T_diff observation take
    the smallest i / A over their observations brighter than `min_signal` (an upper bound of Pd,
    since specular light only adds); if none is that bright, the least squares over all of them.
    Returns pd (T, 3), from_diffuse (T,), defined (T,).
    """
    A = terms.diffuse
    lit = A.min(-1).values > 0
    diff_ok = ((cls == T_DIFF) & usable & lit)[..., None].to(A.dtype)
    num = (diff_ok * A * intensity).sum(0)
    den = (diff_ok * A * A).sum(0)
    from_diffuse = den.min(-1).values > 0
    pd_diff = num / den.clamp_min(1e-30)
    any_ok = usable & lit
    ratio = intensity / A.clamp_min(1e-12)
    bright = any_ok & (intensity.mean(-1) >= min_signal)
    inf = torch.tensor(float("inf"), dtype=A.dtype)
    low = torch.where(bright, ratio.mean(-1), inf).argmin(dim=0)
    pd_bound = ratio.gather(0, low[None, :, None].expand(1, -1, 3))[0]
    w = any_ok[..., None].to(A.dtype)
    pd_ls = (w * A * intensity).sum(0) / (w * A * A).sum(0).clamp_min(1e-30)
    pd_bound = torch.where(bright.any(0)[:, None], pd_bound, pd_ls)
    defined = any_ok.any(dim=0)
    pd = torch.where(from_diffuse[:, None], pd_diff, pd_bound)
    pd = torch.where(defined[:, None], pd, torch.zeros_like(pd)).clamp_min(0.0)
    return pd, from_diffuse, defined


def closed_form_specular(
    terms: LocalTerms,
    intensity: torch.Tensor,
    cls: torch.Tensor,
    usable: torch.Tensor,
    pd: torch.Tensor,
    ps_channels: int = 3,
    sigma_min: float = 0.01,
    sigma_max: float = 0.6,
    min_specular: float = 2.0 / 255.0,
    min_spread_deg: float = 1.0,
):
    """Eq. 3.4-3.5 (weighted line through ln a_k versus x_k). Returns ps (T, C), sigma (T,), determined (T,)."""
    model = terms.brdf
    dtype = terms.theta_h.dtype
    T = terms.theta_h.shape[1]
    if model == "lambertian":
        return (
            torch.zeros(T, ps_channels, dtype=dtype),
            torch.full((T,), sigma_max, dtype=dtype),
            torch.zeros(T, dtype=torch.bool),
        )
    spec_int = intensity - pd[None] * terms.diffuse  # (P, T, 3)
    B = terms.specular
    s_sum = spec_int.sum(-1)
    ok = (cls == T_SPEC) & usable & (B.min(-1).values > 0) & (s_sum > 3 * min_specular)
    a = (spec_int / B.clamp_min(1e-30)).mean(-1).clamp_min(1e-30)  # (P, T) grey specular amplitude
    if model == "torrance_sparrow":
        x, c = terms.theta_h**2, 2.0
    else:
        x, c = torch.tan(terms.theta_h.clamp_max(1.5)) ** 2, 1.0
    y = torch.log(a)
    w = torch.where(ok, s_sum**2, torch.zeros_like(s_sum))
    S0, S1, S2 = w.sum(0), (w * x).sum(0), (w * x * x).sum(0)
    Sy, Sxy = (w * y).sum(0), (w * x * y).sum(0)
    det = S0 * S2 - S1 * S1
    n_ok = ok.sum(0)
    xmin = torch.where(ok, x, torch.full_like(x, float("inf"))).min(0).values
    xmax = torch.where(ok, x, torch.full_like(x, -float("inf"))).max(0).values
    spread = math.radians(min_spread_deg)
    if model == "torrance_sparrow":
        spread_ok = (xmax.clamp_min(0).sqrt() - xmin.clamp_min(0).sqrt()) > spread
    else:
        spread_ok = (torch.atan(xmax.clamp_min(0).sqrt()) - torch.atan(xmin.clamp_min(0).sqrt())) > spread
    slope = (S0 * Sxy - S1 * Sy) / torch.where(det.abs() > 0, det, torch.ones_like(det))
    determined = (n_ok >= 2) & spread_ok & (det.abs() > 0) & (slope < 0)
    sigma = torch.sqrt(-1.0 / (c * torch.where(determined, slope, -torch.ones_like(slope))))
    determined &= (sigma >= sigma_min) & (sigma <= sigma_max)
    sigma = sigma.clamp(sigma_min, sigma_max)
    # Ps per channel: weighted mean over the usable observations of a_k,c / D(theta_k; sigma)
    D = specular_lobe(model, terms.theta_h, sigma[None], terms.spread)  # (P, T)
    a_c = spec_int / B.clamp_min(1e-30)  # (P, T, 3)
    wc = torch.where(ok, D * D, torch.zeros_like(D))[..., None]
    ps = (wc * a_c * D[..., None]).sum(0) / (wc * D[..., None] ** 2).sum(0).clamp_min(1e-30)
    if ps_channels == 1:
        ps = ps.mean(-1, keepdim=True)
    ps = torch.where(determined[:, None], ps.clamp_min(0.0), torch.zeros_like(ps))
    return ps, sigma, determined


def closed_form(terms: LocalTerms, intensity, cls, usable, ps_channels=3, sigma_min=0.01, sigma_max=0.6) -> ClosedForm:
    """Eq. 3.3 then eq. 3.4-3.5 for every texel."""
    pd, from_diff, defined = closed_form_pd(terms, intensity, cls, usable)
    ps, sigma, det = closed_form_specular(terms, intensity, cls, usable, pd, ps_channels, sigma_min, sigma_max)
    return ClosedForm(pd, ps, sigma, from_diff, defined, det & defined)
