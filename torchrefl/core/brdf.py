"""Reflectance models as plain differentiable functions.

All functions broadcast over leading dimensions. Directions are unit vectors in
the world frame: n the surface normal, l towards the light, v towards the camera.
Angles come from atan2(|a x b|, a.b), never acos of a dot product (acos has an
infinite derivative at the specular peak).

The quantity the transport code needs is the cosine-weighted BRDF
    g = f(l, v) * max(n.l, 0),
so that the measured value of a point light is i = kappa * Y / C^2 * g. Keeping
the cosine inside lets the Torrance-Sparrow 1/cos(theta_l) cancel analytically,
which keeps grazing lights finite.

Models (docs/model.md):
- "torrance_sparrow" (eq. 2.9): f = Pd/pi + Ps exp(-theta_h^2 / (2 sigma^2)) / (pi cos_l cos_v).
  With kappa = pi: i = Y/C^2 (Pd cos_l + Ps exp(-theta_h^2/(2 sigma^2)) / cos_v)  (eq. 2.9).
- "ward" (eq. 5.9): f = Pd/pi + Ps exp(-tan^2 theta_h / sigma^2) / (4 pi sigma^2),
  optionally times 1/sqrt(cos_l cos_v) (the standard Ward normalisation; the seed drops it).

Diffuse part (reflectance.diffuse):
- "lambert" (eq. 2.9): Pd / pi.
- "minnaert": Pd / pi * (cos_l cos_v)^(k - 1), Minnaert's generalisation of Lambert (reciprocal;
  k = 1 is Lambert, k > 1 darker than Lambert towards grazing light and view). One exponent k for
  the object; local transport only (radiosity and photon levels carry Lambertian light).

Numerical guards (the only clamps in the physics, documented here):
- cos_v is clamped below at COS_EPS before dividing (grazing views are excluded
  from fitting anyway by the validity mask; the clamp keeps values finite);
- cos(theta_h) is clamped below at COS_EPS inside tan(theta_h);
- sigma is clamped below at SIGMA_EPS inside the exponent;
- cos_l and cos_v are clamped below at COS_EPS inside the Minnaert power (finite gradients in k and
  in the angles at grazing; the factor is 0 where cos_l <= 0 anyway).
"""

from __future__ import annotations

import math

import torch

from torchrefl.core.lobe_spread import spread_lobe_dsigma
from torchrefl.errors import ConfigError

COS_EPS = 1e-4
SIGMA_EPS = 1e-4
_TINY = 1e-30

BRDF_NAMES = ("torrance_sparrow", "ward", "ward_normalised", "lambertian")
DIFFUSE_MODELS = ("lambert", "minnaert")


def check_brdf_name(name: str, where: str = "fit.brdf") -> str:
    """Return `name` if it is a known BRDF, else raise ConfigError naming `where`."""
    if name not in BRDF_NAMES:
        raise ConfigError(f"{where}: unknown BRDF '{name}', expected one of {', '.join(BRDF_NAMES)}")
    return name


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(..., 3) x (..., 3) -> (...) dot product."""
    return (a * b).sum(dim=-1)


def safe_normalize(x: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """x / |x| with a floor on |x| (a zero vector stays finite)."""
    return x / torch.sqrt((x * x).sum(dim=-1, keepdim=True) + eps * eps)


def angle_between(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(...) angle in radians between vectors a and b (..., 3), by atan2(|a x b|, a.b).

    The norm of the cross product is taken as sqrt(|a x b|^2 + tiny) so that the
    gradient stays finite where a and b are parallel (the specular peak).
    """
    cross = torch.linalg.cross(a, b, dim=-1)
    s = torch.sqrt((cross * cross).sum(dim=-1) + _TINY)
    return torch.atan2(s, dot(a, b))


def half_vector(l: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """(..., 3) unit half vector (l + v) / |l + v|."""
    return safe_normalize(l + v)


def half_angle(n: torch.Tensor, l: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """(...) theta_h: angle between the normal and the half vector (eq. 2.15, via atan2)."""
    return angle_between(n, half_vector(l, v))


def specular_lobe(
    model: str, theta_h: torch.Tensor, sigma: torch.Tensor, spread: torch.Tensor | None = None
) -> torch.Tensor:
    """The specular distribution D so that the specular part of f*cos_l is Ps * D * geometric factor.

    torrance_sparrow: exp(-theta_h^2 / (2 sigma^2))
    ward*:            exp(-tan^2 theta_h / sigma^2) / (4 pi sigma^2)
    theta_h, sigma broadcastable; returns their broadcast shape. spread: None, or (..., 2 or 3) the observations'
    footprint spread of the half-angle offset (radians^2, along and across it; the offset's shift, radians): the
    lobe averaged over it (core.lobe_spread).
    """
    if spread is not None and model != "lambertian":
        return spread_lobe_dsigma(model, theta_h, sigma, spread, SIGMA_EPS, COS_EPS)[0]
    sig = sigma.clamp_min(SIGMA_EPS)
    if model == "torrance_sparrow":
        return torch.exp(-(theta_h * theta_h) / (2.0 * sig * sig))
    if model in ("ward", "ward_normalised"):
        c = torch.cos(theta_h).clamp_min(COS_EPS)
        tan2 = (torch.sin(theta_h) / c) ** 2
        return torch.exp(-tan2 / (sig * sig)) / (4.0 * math.pi * sig * sig)
    if model == "lambertian":
        return torch.zeros_like(theta_h + sig)
    raise ConfigError(f"fit.brdf: unknown BRDF '{model}', expected one of {', '.join(BRDF_NAMES)}")


def specular_lobe_dsigma(
    model: str, theta_h: torch.Tensor, sigma: torch.Tensor, spread: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(D, dD/dsigma) of specular_lobe, the derivative in closed form (0 where sigma < SIGMA_EPS, the clamp):
    torrance_sparrow D theta_h^2 / sigma^3, ward* D (2 tan^2 theta_h / sigma^3 - 2 / sigma); spread as
    specular_lobe's."""
    if spread is not None and model != "lambertian":
        return spread_lobe_dsigma(model, theta_h, sigma, spread, SIGMA_EPS, COS_EPS)
    sig = sigma.clamp_min(SIGMA_EPS)
    live = (sigma >= SIGMA_EPS).to(sig.dtype)
    if model == "torrance_sparrow":
        t2 = theta_h * theta_h
        D = torch.exp(-t2 / (2.0 * sig * sig))
        return D, D * t2 * live / (sig * sig * sig)
    if model in ("ward", "ward_normalised"):
        c = torch.cos(theta_h).clamp_min(COS_EPS)
        tan2 = (torch.sin(theta_h) / c) ** 2
        D = torch.exp(-tan2 / (sig * sig)) / (4.0 * math.pi * sig * sig)
        return D, D * (2.0 * tan2 / (sig * sig) - 2.0) * live / sig
    if model == "lambertian":
        zero = torch.zeros_like(theta_h + sig)
        return zero, zero
    raise ConfigError(f"fit.brdf: unknown BRDF '{model}', expected one of {', '.join(BRDF_NAMES)}")


#: specular_geometry's G as a power law, (exponent of cos_v, exponent of cos_l) per BRDF: what its slope across a
#: footprint is (capture.footprint_spread); tests/core/test_brdf.py holds the two together
SPECULAR_GEOMETRY_EXPONENTS = {
    "torrance_sparrow": (-1.0, 0.0),
    "ward": (0.0, 1.0),
    "ward_normalised": (-0.5, 0.5),
    "lambertian": (0.0, 0.0),
}


def specular_geometry(model: str, cos_l: torch.Tensor, cos_v: torch.Tensor) -> torch.Tensor:
    """The factor G such that the specular part of f * max(cos_l, 0) equals Ps * D * G.

    torrance_sparrow: 1 / (pi cos_v)              (cos_l cancels)
    ward:             cos_l                       (seed's eq. 5.9)
    ward_normalised:  sqrt(cos_l / cos_v)         (cos_l / sqrt(cos_l cos_v))
    Zero where cos_l <= 0.
    """
    cl = cos_l.clamp_min(0.0)
    cv = cos_v.clamp_min(COS_EPS)
    lit = (cos_l > 0).to(cl.dtype)
    if model == "torrance_sparrow":
        return lit / (math.pi * cv)
    if model == "ward":
        return cl
    if model == "ward_normalised":
        return torch.sqrt(cl / cv + _TINY) * lit
    if model == "lambertian":
        return torch.zeros_like(cl * cv)
    raise ConfigError(f"fit.brdf: unknown BRDF '{model}', expected one of {', '.join(BRDF_NAMES)}")


def minnaert_factor(cos_l: torch.Tensor, cos_v: torch.Tensor, k) -> torch.Tensor:
    """(cos_l cos_v)^(k - 1) with both cosines clamped below at COS_EPS; k a float or a tensor (scalar)."""
    log_lv = torch.log(cos_l.clamp_min(COS_EPS)) + torch.log(cos_v.clamp_min(COS_EPS))
    return torch.exp((k - 1.0) * log_lv)


def diffuse_term(cos_l: torch.Tensor, cos_v: torch.Tensor, k=1.0) -> torch.Tensor:
    """The diffuse part of f * max(cos_l, 0) per unit Pd: max(cos_l, 0) / pi, times the Minnaert
    factor (cos_l cos_v)^(k - 1) unless k is exactly 1 (Lambert)."""
    lam = cos_l.clamp_min(0.0) / math.pi
    if not isinstance(k, torch.Tensor) and float(k) == 1.0:
        return lam
    return lam * minnaert_factor(cos_l, cos_v, k)


def cosine_weighted_brdf(
    model: str,
    n: torch.Tensor,
    l: torch.Tensor,
    v: torch.Tensor,
    pd: torch.Tensor,
    ps: torch.Tensor,
    sigma: torch.Tensor,
    diffuse_exponent=1.0,
) -> torch.Tensor:
    """g = f(l, v) * max(n.l, 0), per channel.

    n, l, v: (..., 3) unit vectors; pd: (..., C) diffuse reflectance; ps: (..., C) or (..., 1)
    specular reflectance (grey broadcasts); sigma: (...) roughness in radians; diffuse_exponent:
    Minnaert's k (1 = Lambert), a float or a scalar tensor.
    Returns (..., C).
    """
    cos_l = dot(n, l)
    cos_v = dot(n, v)
    theta_h = half_angle(n, l, v)
    diffuse = pd * diffuse_term(cos_l, cos_v, diffuse_exponent).unsqueeze(-1)
    spec = (specular_lobe(model, theta_h, sigma) * specular_geometry(model, cos_l, cos_v)).unsqueeze(-1)
    return diffuse + ps * spec


def brdf(model: str, n, l, v, pd, ps, sigma) -> torch.Tensor:
    """The BRDF value f(l, v) itself (..., C); diverges like 1/cos_l at grazing light for Torrance-Sparrow.

    Provided for rendering and photon scattering; the fitter uses cosine_weighted_brdf.
    """
    cos_l = dot(n, l).clamp_min(COS_EPS)
    return cosine_weighted_brdf(model, n, l, v, pd, ps, sigma) / cos_l.unsqueeze(-1)
