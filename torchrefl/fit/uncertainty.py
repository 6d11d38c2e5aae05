"""Per-texel uncertainty of the fitted Pd (per channel), Ps and sigma: the Gauss-Newton (Laplace) approximation.

With the level's indirect light held at the fitted Pd (TransportLevel.texel_model), each texel's predicted images
depend on its own parameters theta = (Pd (3), Ps (C), sigma) only, so the curvature of the fit's objective at the
solution is one K x K block per texel (K = 4 + C):

    I_t = sum over the texel's fitted observations p and channels c of  w_ptc / s_c^2  J_ptc J_ptc^T,

with J_ptc = d(255 i_hat_ptc) / d theta (8-bit DN per parameter unit, torchrefl.fit.texel_jacobian: in closed form
for a TexelModel, by forward-mode passes of any other model; in the natural parameters, not the optimiser's raw
ones), w the fit's robust-loss weights (torchrefl.fit.texel_lm.irls_weight) and s_c the sensor noise of channel c in
DN. The covariance is (I_t + diag(1 / v))^-1 with v the variance of a parameter spread uniformly over its physical
range (Pd, Ps in [0, 1] and [0, ps_max], sigma in
[sigma_min, sigma_max]): a broad prior that leaves a well-determined parameter's std alone (its information is far
larger) and keeps an undetermined one (sigma of a texel without a highlight) finite, at the range's std.

Noise: capture.noise_dn when given; else per channel from the fit's residuals, robustly and with the
degrees of freedom accounted for: each residual is divided by sqrt(1 - h) (h its leverage, the hat matrix's
diagonal w / s_c^2 J^T Cov J, at the raw residuals' MAD; a lobe not measured by the texel is held, not fitted, so
its block of Cov counts zero) and s_c = 1.4826 MAD of those (over an even stride of at most NOISE_TEXELS
texels). A level whose predictions carry their own Monte Carlo noise (the photon level's caches:
TransportLevel.prediction_variance, a mean square measured from its last averaged refresh) adds that variance per
channel: the parameters were fitted against caches with that noise, and the residuals' robust spread leaves out
most of its heavy tail.

Texels whose Ps and sigma the fit did not estimate from their own observations (coverage other than "measured":
the lobe of their colour, their neighbours' or the object's) have Ps, sigma std at the range's std, marked not
determined (`lobe_measured` False), and Pd's std with that lobe free within the broad prior (Pd's part of the
whole block's covariance): a borrowed lobe may be off, and Pd is as uncertain as the lobe its observations depend
on (where they all lie inside the lobe, a grey part of Pd and the lobe trade; where some are diffuse-only, Pd's std
is about that of the lobe held). With
fit.specular: shared, the object's one lobe has the information of all texels (the Schur complements of their Pd
blocks summed) and each texel's Pd std includes the lobe's uncertainty.

`covariance(information, prior_var)` is the function a planner reuses: add a candidate light's information to a
texel's block and read the covariance it would leave.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import torch

from torchrefl.config import Config
from torchrefl.core.progress import Stages
from torchrefl.core.robust import robust_std
from torchrefl.fit.initialise import COVER_FULL
from torchrefl.fit.result import FitResult
from torchrefl.fit.texel_jacobian import ChannelInformation, DenseJacobian, Jacobian, jacobian
from torchrefl.fit.texel_lm import irls_weight
from torchrefl.transport.levels.base import TransportLevel

#: leverages are capped here (an observation that alone fixes a parameter has h -> 1 and no residual)
MAX_LEVERAGE = 0.9
#: the noise is estimated from at most this many texels' residuals (an even stride over the texels): some 10^5
#: residuals per channel, whose MAD is within about 0.5 % of all texels'; their leverages cost a covariance each
NOISE_TEXELS = 32768


@dataclass
class Uncertainty:
    """One std per fitted parameter and texel (T texels), and the noise level behind them.

    pd_std (T, 3), ps_std (T, C), sigma_std (T,): standard deviations in the parameters' units (finite; a parameter
    the data do not determine has about its range's std); lobe_measured (T,) bool: Ps and sigma were estimated from
    the texel's own observations (False: their std is the range's, not determined); noise_dn (3,): the sensor
    noise per channel in 8-bit DN; noise_source: 'residuals' (estimated) or 'capture.noise_dn'.
    """

    pd_std: torch.Tensor
    ps_std: torch.Tensor
    sigma_std: torch.Tensor
    lobe_measured: torch.Tensor
    noise_dn: torch.Tensor
    noise_source: str
    #: (3,) the part of noise_dn that is the level's own Monte Carlo noise in its predictions, in DN (None: none)
    model_noise_dn: Optional[torch.Tensor] = None


@dataclass(frozen=True)
class ParameterRanges:
    """The physical ranges of the parameters whose uniform spread is the broad prior: Pd in [0, 1], Ps in
    [0, ps_max], sigma in [sigma_min, sigma_max]."""

    ps_max: float
    sigma_min: float
    sigma_max: float

    def prior_var(self, ps_channels: int, dtype=torch.float64) -> torch.Tensor:
        """(K,) the variances of a uniform spread over each range, in the order Pd (3), Ps (C), sigma."""
        widths = [1.0] * 3 + [min(self.ps_max, 1e3)] * ps_channels + [self.sigma_max - self.sigma_min]
        return torch.tensor(widths, dtype=dtype) ** 2 / 12.0


def information(J: torch.Tensor, weight: torch.Tensor, noise_dn: torch.Tensor) -> torch.Tensor:
    """(T, K, K) float64 Fisher information per texel: sum over p, c of weight / noise_dn[c]^2 J J^T;
    J (P, T, 3, K) in DN per parameter unit, weight (P, T, 3), noise_dn (3,) per channel in DN."""
    return DenseJacobian(J).information(weight).scaled(noise_dn)


def covariance(info: torch.Tensor, prior_var: torch.Tensor) -> torch.Tensor:
    """(..., K, K) the covariance (info + diag(1 / prior_var))^-1 of each texel's parameters: info (..., K, K)
    symmetric positive semi-definite, prior_var (K,) > 0 the broad prior's variances. Differentiable."""
    A = info + torch.diag_embed(1.0 / prior_var.to(info))
    return torch.cholesky_inverse(torch.linalg.cholesky(A))


def leverage(J: Jacobian, weight: torch.Tensor, noise_dn: torch.Tensor, cov: torch.Tensor) -> torch.Tensor:
    """(P, T, 3) each observation's leverage h = weight / s_c^2 J^T cov J (the hat matrix's diagonal), float64;
    the quadratic forms in J's dtype (float64 sums are needed for the information only)."""
    return J.quadratic(cov).double() * weight.double() / noise_dn.double().square()


def mad_noise(r: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(3,) 1.4826 x the median absolute deviation of r (P, T, 3) per channel over mask (P, T) (0 where empty)."""
    out = []
    for c in range(r.shape[-1]):
        x = r[..., c][mask].double()
        out.append(robust_std(x) if x.numel() else x.new_zeros(()))
    return torch.stack(out)


def residual_noise(r, J, weight, per_channel, mask, prior_var, lobe_measured) -> torch.Tensor:
    """(3,) per-channel noise in DN from the fit's residuals r (P, T, 3), leverage-corrected (module docstring):
    the leverages at the raw residuals' MAD (they depend on the noise only through the broad prior's share), those
    of a texel whose lobe was not measured from its Pd block alone (its held lobe's broad-prior variance is no
    leverage: counted, it put h far over 1 wherever the lobe shows, and the cap's 1 / sqrt(1 - 0.9) tripled those
    residuals); over every k-th texel where there are more than NOISE_TEXELS."""
    step = noise_stride(r.shape[1])
    if step > 1:
        r, J, weight, mask = r[:, ::step], J.texels(slice(None, None, step)), weight[:, ::step], mask[:, ::step]
        per_channel, lobe_measured = per_channel.texels(slice(None, None, step)), lobe_measured[::step]
    s = mad_noise(r, mask).clamp_min(1e-3)
    cov = fitted_covariance(per_channel.scaled(s), prior_var, lobe_measured)
    h = leverage(J, weight, s, cov).clamp(0.0, MAX_LEVERAGE)
    return mad_noise(r.double() / torch.sqrt(1.0 - h), mask).clamp_min(1e-3)


def fitted_covariance(info: torch.Tensor, prior_var: torch.Tensor, lobe_measured: torch.Tensor) -> torch.Tensor:
    """(T, K, K) the covariance of what the fit moved, for the leverages: the whole block where the texel's lobe
    was measured; elsewhere the Pd block alone (the lobe was held, not fitted to the residuals: it takes no
    leverage) and zeros for the lobe."""
    prior_var = prior_var.to(info)
    measured, held = lobe_measured.nonzero()[:, 0], (~lobe_measured).nonzero()[:, 0]
    cov = torch.zeros_like(info)
    cov.index_copy_(0, measured, covariance(info.index_select(0, measured), prior_var))
    block = torch.zeros(len(held), *info.shape[1:], dtype=info.dtype, device=info.device)
    block[:, :3, :3] = covariance(info.index_select(0, held)[:, :3, :3], prior_var[:3])
    cov.index_copy_(0, held, block)
    return cov


def texel_covariance(info: torch.Tensor, prior_var: torch.Tensor, lobe_measured: torch.Tensor) -> torch.Tensor:
    """(T, K, K) the covariance of each texel: the whole block where its lobe was measured; elsewhere Pd's part of
    the whole block (the held lobe free within the broad prior: Pd is as uncertain as the lobe its observations
    depend on) and the lobe at the broad prior's variance, uncorrelated."""
    prior_var = prior_var.to(info)
    cov = covariance(info, prior_var)
    held = ~lobe_measured.to(cov.device)
    cov[held, :3, 3:] = 0.0
    cov[held, 3:, :3] = 0.0
    cov[held, 3:, 3:] = torch.diag(prior_var[3:])
    return cov


def shared_lobe_covariance(info: torch.Tensor, prior_var: torch.Tensor, estimated: torch.Tensor) -> torch.Tensor:
    """(T, K, K) the covariance with one lobe for the whole object: the lobe's information is the sum over the
    estimated texels of their blocks' Schur complements; each texel's Pd covariance adds the lobe's through its
    coupling (A^-1 + A^-1 B S B^T A^-1)."""
    A, B, C = info[:, :3, :3], info[:, :3, 3:], info[:, 3:, 3:]
    A_inv = covariance(A, prior_var[:3])
    schur = (C - B.transpose(1, 2) @ A_inv @ B)[estimated].sum(0)
    S = covariance(schur, prior_var[3:])
    G = A_inv @ B
    cov = torch.zeros_like(info)
    cov[:, :3, :3] = A_inv + G @ S @ G.transpose(1, 2)
    cov[:, :3, 3:] = -G @ S
    cov[:, 3:, :3] = cov[:, :3, 3:].transpose(1, 2)
    cov[:, 3:, 3:] = S
    return cov


@dataclass
class Evidence:
    """What a fit's observations say of its texels' parameters: r (P, T, 3) the residuals in DN, J the Jacobian
    (torchrefl.fit.texel_jacobian), weight (P, T, 3) the robust loss's weights at the fitted observations,
    per_channel J.information(weight), mask (P, T) the fitted observations."""

    r: torch.Tensor
    J: Jacobian
    weight: torch.Tensor
    per_channel: ChannelInformation
    mask: torch.Tensor


def texel_evidence(model: Callable, pd, ps, sigma, intensity, fit_mask, loss: str, loss_scale_8bit: float) -> Evidence:
    """The Evidence of the texels model (pd, ps, sigma) -> (P, T, 3) describes, at their fitted values."""
    with torch.no_grad():
        r = (model(pd, ps, sigma) - intensity) * 255.0
    J = jacobian(model, pd, ps, sigma)
    mask = fit_mask.to(pd.device)
    weight = irls_weight(r, loss, loss_scale_8bit) * mask[..., None].to(r.dtype)
    return Evidence(r, J, weight, J.information(weight), mask)


def noise_stride(texels: int) -> int:
    """The stride over the texels whose residuals estimate the noise (at most NOISE_TEXELS of them)."""
    return -(-texels // NOISE_TEXELS)


def texel_uncertainty(
    model: Callable,
    pd: torch.Tensor,
    ps: torch.Tensor,
    sigma: torch.Tensor,
    intensity: torch.Tensor,
    fit_mask: torch.Tensor,
    lobe_measured: torch.Tensor,
    ranges: ParameterRanges,
    loss: str = "huber",
    loss_scale_8bit: float = 3.0,
    noise_dn: float | None = None,
    shared_lobe: torch.Tensor | None = None,
    model_var: torch.Tensor | None = None,
) -> Uncertainty:
    """The std of every texel's fitted parameters (module docstring).

    model: (pd, ps, sigma) -> (P, T, 3), each texel's images a function of its own parameters (texel_model);
    pd (T, 3), ps (T, C), sigma (T,) the fitted values; intensity (P, T, 3) measured; fit_mask (P, T) the fitted
    observations; lobe_measured (T,) bool: Ps and sigma estimated from the texel's own observations; ranges: the
    broad prior; loss, loss_scale_8bit: the fit's robust loss; noise_dn: the known sensor noise in DN (None:
    estimated from the residuals); shared_lobe: (T,) bool the estimated texels sharing one lobe (fit.specular:
    shared), None for a lobe per texel; model_var: (3,) DN^2 the model's own Monte Carlo noise per observation
    (TransportLevel.prediction_variance), added to the sensor noise's variance."""
    lobe_measured = lobe_measured.to(pd.device)
    ev = texel_evidence(model, pd, ps, sigma, intensity, fit_mask, loss, loss_scale_8bit)
    return uncertainty_of(ev.per_channel, ev, lobe_measured, ranges, ps.shape[1], noise_dn, shared_lobe, model_var)


def uncertainty_of(
    per_channel: ChannelInformation,
    noise_evidence: Evidence,
    lobe_measured: torch.Tensor,
    ranges: ParameterRanges,
    C: int,
    noise_dn: float | None = None,
    shared_lobe: torch.Tensor | None = None,
    model_var: torch.Tensor | None = None,
) -> Uncertainty:
    """texel_uncertainty's result from every texel's per_channel information and the Evidence of the
    texels the noise is estimated on (all texels, or every noise_stride-th: residual_noise; lobe_measured (T,) of
    all texels)."""
    prior_var = ranges.prior_var(C)
    if noise_dn is None:
        ev, step = noise_evidence, noise_stride(per_channel.values.shape[1])
        measured = lobe_measured if ev.r.shape[1] == per_channel.values.shape[1] else lobe_measured[::step]
        s, source = residual_noise(ev.r, ev.J, ev.weight, ev.per_channel, ev.mask, prior_var, measured), "residuals"
    else:
        s, source = torch.full((3,), float(noise_dn), dtype=torch.float64), "capture.noise_dn"
    model_noise = None
    if model_var is not None:
        model_var = model_var.to(s)
        s, model_noise = torch.sqrt(s.square() + model_var), model_var.sqrt()
    info = per_channel.scaled(s)
    if shared_lobe is not None:
        cov = shared_lobe_covariance(info, prior_var.to(info.device), shared_lobe.to(info.device))
    else:
        cov = texel_covariance(info, prior_var.to(info.device), lobe_measured)
    std = torch.diagonal(cov, dim1=1, dim2=2).clamp_min(0.0).sqrt().cpu()
    measured = lobe_measured.cpu() if shared_lobe is None else shared_lobe.cpu()
    model_noise = None if model_noise is None else model_noise.cpu()
    return Uncertainty(std[:, :3], std[:, 3 : 3 + C], std[:, -1], measured, s.cpu(), source, model_noise)


def fit_uncertainty(cfg: Config, level: TransportLevel, result: FitResult, stages: Stages) -> Uncertainty:
    """The Uncertainty of a finished fit (torchrefl.fit.pipeline): the level's texel model at the estimate (the
    interreflection held at the fitted Pd), the fitted observations, the lobes measured by the texels themselves
    (coverage "measured"; with fit.specular: shared, the one lobe of all estimated texels)."""
    inp = level.inputs
    with stages.stage("uncertainty"), torch.no_grad():
        dtype = inp.obs.intensity.dtype
        pd, ps, sigma = (x.to(inp.device, dtype) for x in (result.pd, result.ps, result.sigma))
        rc = cfg.reflectance
        shared = cfg.fit.specular == "shared"
        ranges = ParameterRanges(rc.ps_max, rc.sigma_min, rc.sigma_max)
        fitted = result.fit_mask & result.estimated[None]
        if inp.chunks is not None and level.name == "local":
            from torchrefl.fit.texel_chunks import chunked_uncertainty

            measured = (result.coverage == COVER_FULL).to(inp.device)
            intensity = inp.obs.intensity.to(inp.device)
            args = (cfg.fit.loss, cfg.fit.loss_scale_8bit, cfg.capture.noise_dn)
            return chunked_uncertainty(
                inp.chunks, inp.local_terms(), pd, ps, sigma, intensity, fitted, measured, ranges, *args
            )
        return texel_uncertainty(
            level.texel_model(pd),
            pd,
            ps,
            sigma,
            inp.obs.intensity.to(inp.device),
            fitted,
            result.coverage == COVER_FULL,
            ranges,
            cfg.fit.loss,
            cfg.fit.loss_scale_8bit,
            cfg.capture.noise_dn,
            result.estimated if shared else None,
            level.prediction_variance(),
        )
