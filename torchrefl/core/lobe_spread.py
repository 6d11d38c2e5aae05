"""The specular lobe averaged over an observation's footprint: the lobe convolved with a Gaussian spread of the
half-angle offset.

A pixel value read over a texel's footprint (several pixels, each integrating over its area) sees the surface at
a range of points: on a curved surface the normal turns across the footprint (and, for near lights and cameras,
the half vector turns too), so the measured highlight is the lobe averaged over a spread of half-angle offsets,
not the lobe at the footprint's centre. For a Gaussian-shaped lobe exp(-|d|^2 / (2 s^2)) of the 2-D half-angle
offset d (|d| ~ theta_h; s^2 = sigma^2 for Torrance-Sparrow, sigma^2 / 2 in tan theta_h for Ward) and offsets
spread with variance `along` in d's direction and `across` perpendicular to it, the average is

    s / sqrt(s^2 + along) * s / sqrt(s^2 + across) * exp(-|d|^2 / (2 (s^2 + along)))

(exact for a Gaussian spread aligned with d; first-order exact in the spread otherwise). A third value, a shift
of |d| (radians), moves the offset the average is taken at: the specular weight (1 / cos_v, the falloff) varies
across the footprint too and tilts the mean towards where it is larger. With zero spread it is the lobe itself.
The loader measures all three (capture.footprint_spread).
"""

from __future__ import annotations

import math

import torch

from torchrefl.errors import ConfigError


def spread_lobe_dsigma(
    model: str, theta_h: torch.Tensor, sigma: torch.Tensor, spread: torch.Tensor, sigma_eps: float, cos_eps: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """(D, dD/dsigma) of the footprint-averaged lobe (module doc) of torrance_sparrow or ward*; theta_h (...),
    sigma broadcastable, spread (..., 2 or 3): the variances along and across (radians^2, >= 0) and the shift of
    theta_h (radians; none without a third value). sigma is clamped below at sigma_eps (derivative 0 there),
    cos(theta_h) at cos_eps inside tan(theta_h)."""
    sig = sigma.clamp_min(sigma_eps)
    live = (sigma >= sigma_eps).to(sig.dtype)
    along, across = spread[..., 0], spread[..., 1]
    theta = theta_h if spread.shape[-1] < 3 else (theta_h + spread[..., 2]).clamp_min(0.0)
    if model == "torrance_sparrow":
        x2, s2, k = theta * theta, sig * sig, 1.0
    elif model in ("ward", "ward_normalised"):
        c = torch.cos(theta).clamp_min(cos_eps)
        x2, s2, k = (torch.sin(theta) / c) ** 2, sig * sig / 2.0, 2.0
    else:
        raise ConfigError(f"fit.brdf: no footprint spread for BRDF '{model}' (torrance_sparrow, ward*)")
    a, b = s2 + along, s2 + across
    # Torrance-Sparrow: s^2 / sqrt(a b) exp(-x2 / (2 a)); Ward (s^2 = sigma^2 / 2): exp(-x2 / (2 a)) / (8 pi sqrt(a b))
    scale = s2 / torch.sqrt(a * b) if k == 1.0 else 1.0 / (8.0 * math.pi * torch.sqrt(a * b))
    D = scale * torch.exp(-x2 / (2.0 * a))
    ds2 = 2.0 * sig / k  # d s^2 / d sigma
    dlog = (1.0 / s2 if k == 1.0 else 0.0) - 0.5 / a - 0.5 / b + x2 / (2.0 * a * a)
    return D, D * dlog * ds2 * live
