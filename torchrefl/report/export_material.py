"""The fitted reflectance as a glTF 2.0 metallic-roughness material with KHR_materials_specular (docs/exports.md).

glTF's dielectric (metallic 0) with KHR_materials_specular reflects
    f = F * D_a(h) * Vis_a(l, v) + (1 - max_c F) * base / pi,
    F = f0 + (f90 - f0) (1 - v.h)^5,  f0 = min(0.04 * specularColor, 1) * specular,  f90 = specular,
with D_a the Trowbridge-Reitz (GGX) distribution and Vis_a the separable Smith visibility of a = roughness^2.
The fitted model reflects f = Pd / pi + Ps * lobe_sigma(l, v) (core/brdf.py: Torrance-Sparrow or Ward).

Conversion (per texel):
- specularColor = 25 * t with t_c = Ps_c / max_c Ps, so that f0 = specular * t: the brightest channel has
  f0 = f90 = specular, F is `specular` in that channel at every angle (the fitted lobes have no Fresnel term);
- specular = k(sigma) * max_c Ps and roughness = sqrt(a(sigma)), from a 1-D table per BRDF: for each sigma,
  (a, k) minimise the squared difference of the cosine-weighted lobes, k D_a Vis_a cos_l against lobe_sigma cos_l,
  integrated over the light directions (solid angle) of views 0, 20, 40 and 60 degrees from the normal, over
  the half-vector cone where either lobe carries light (LOBE_SPAN sigma, at most 85 degrees): k in closed form
  for each a, a by a bounded scalar search on log a;
- base colour = Pd: glTF's dielectric darkens the diffuse part by (1 - specular) (it moves the specular share
  out of the diffuse); the base colour is kept equal to the fitted Pd (the exported texture is the Pd map) and
  this darkening is part of the measured conversion error (docs/results/exports.md).
The one-line formula the fit is measured against, the two lobes' widths and peaks equated at theta_h = 0 for
small sigma: Torrance-Sparrow roughness = sqrt(sqrt(2) sigma), specular = 8 sigma^2 max_c Ps; Ward roughness =
sqrt(sigma), specular = max_c Ps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch
from scipy.optimize import minimize_scalar

from torchrefl.core import brdf as brdf_mod

#: sigma values of the table (rad), log-spaced; sigma outside is clamped to its ends.
TABLE_SIGMA = np.geomspace(0.003, 1.5, 28)
#: view directions' angles from the normal (degrees) over which the lobes are matched, equally weighted
FIT_VIEWS_DEG = (0.0, 20.0, 40.0, 60.0)
#: half-vector cone of the match: this many sigma, at most MAX_HALF_DEG
LOBE_SPAN = 6.0
MAX_HALF_DEG = 85.0
#: the f0 of glTF's default dielectric (ior 1.5) that KHR_materials_specular's specularColor multiplies
DIELECTRIC_F0 = 0.04
#: specularColorFactor: with it the specular colour texture t gives f0 = specular * t (min(0.04 * 25 t, 1) = t)
SPECULAR_COLOR_FACTOR = 1.0 / DIELECTRIC_F0
ALPHA_BOUNDS = (1e-4, 1.0)


@dataclass(frozen=True)
class LobeTable:
    """The fitted sigma -> (a, k) table of one BRDF: sigma (N,) rad, alpha (N,) = roughness^2, gain (N,) k,
    residual (N,) the relative RMS difference of the matched lobes (sqrt of squared error / squared target)."""

    brdf: str
    sigma: np.ndarray
    alpha: np.ndarray
    gain: np.ndarray
    residual: np.ndarray

    def lookup(self, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(alpha, gain) for sigma (...) rad, interpolated linearly in log sigma, log alpha and log k."""
        s = np.log(np.clip(np.asarray(sigma, dtype=np.float64), self.sigma[0], self.sigma[-1]))
        x = np.log(self.sigma)
        return np.exp(np.interp(s, x, np.log(self.alpha))), np.exp(np.interp(s, x, np.log(self.gain)))


@dataclass(frozen=True)
class GltfMaterial:
    """Per-texel glTF parameters on the texel grid (H, W): base_color (H, W, 3) linear, roughness (H, W),
    specular (H, W) the KHR_materials_specular strength, specular_color (H, W, 3) the colour texture t in [0, 1]
    (specularColor = SPECULAR_COLOR_FACTOR * t); metallic is 0 everywhere."""

    base_color: np.ndarray
    roughness: np.ndarray
    specular: np.ndarray
    specular_color: np.ndarray


def _directions(sigma: float) -> tuple[np.ndarray, ...]:
    """cos_l, cos_v, theta_h, cos_vh and solid-angle weights of the light directions the match covers: for each
    view in FIT_VIEWS_DEG, half vectors on a polar grid in the cone of LOBE_SPAN sigma (midpoint rule), the
    light the mirror of the view about h, weight dω_l = 4 (v.h) sin(theta_h) dtheta_h dphi; lights below the
    horizon dropped."""
    top = min(LOBE_SPAN * sigma, math.radians(MAX_HALF_DEG))
    nt, nphi = 64, 32
    dt, dphi = top / nt, 2 * math.pi / nphi
    th = (np.arange(nt) + 0.5) * dt
    ph = (np.arange(nphi) + 0.5) * dphi
    T, P = np.meshgrid(th, ph, indexing="ij")
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    out = []
    for deg in FIT_VIEWS_DEG:
        a = math.radians(deg)
        v = np.array([math.sin(a), 0.0, math.cos(a)])
        vh = h @ v
        l = 2 * vh[:, None] * h - v
        keep = (l[:, 2] > 1e-3) & (vh > 0)
        w = 4 * vh * np.sin(T).ravel() * dt * dphi
        out.append((l[keep, 2], np.full(keep.sum(), v[2]), T.ravel()[keep], vh[keep], w[keep]))
    return tuple(np.concatenate(parts) for parts in zip(*out))


def ggx_lobe(alpha, cos_l, cos_v, cos_h):
    """glTF's specular_brdf D * Vis for a = alpha (GGX distribution, separable Smith visibility), numpy."""
    a2 = alpha * alpha
    d = a2 / (math.pi * (cos_h * cos_h * (a2 - 1.0) + 1.0) ** 2)
    vis = 1.0 / (
        (cos_l + np.sqrt(a2 + (1.0 - a2) * cos_l * cos_l)) * (cos_v + np.sqrt(a2 + (1.0 - a2) * cos_v * cos_v))
    )
    return d * vis


def fitted_lobe(brdf: str, sigma, cos_l, cos_v, theta_h) -> np.ndarray:
    """The fitted model's specular part of f * cos_l per unit Ps (core/brdf.py), numpy in, numpy out."""
    t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))
    lobe = brdf_mod.specular_lobe(brdf, t(theta_h), t(sigma)) * brdf_mod.specular_geometry(brdf, t(cos_l), t(cos_v))
    return lobe.numpy()


def match_lobe(brdf: str, sigma: float) -> tuple[float, float, float]:
    """(alpha, k, relative RMS residual) of the least-squares match of k * GGX to the fitted lobe at sigma."""
    cl, cv, th, vh, w = _directions(sigma)
    target = fitted_lobe(brdf, sigma, cl, cv, th)
    ch = np.cos(th)
    norm = float((w * target * target).sum())

    def solve(log_alpha: float) -> tuple[float, float]:
        model = ggx_lobe(math.exp(log_alpha), cl, cv, ch) * cl
        k = float((w * model * target).sum() / max((w * model * model).sum(), 1e-300))
        return k, float((w * (k * model - target) ** 2).sum())

    guess = math.log(min(max(math.sqrt(2.0) * sigma, ALPHA_BOUNDS[0]), ALPHA_BOUNDS[1]))
    lo, hi = math.log(ALPHA_BOUNDS[0]), math.log(ALPHA_BOUNDS[1])
    best = minimize_scalar(lambda x: solve(x)[1], bounds=(max(lo, guess - 3.0), min(hi, guess + 3.0)), method="bounded")
    k, err = solve(best.x)
    return math.exp(best.x), k, math.sqrt(err / max(norm, 1e-300))


@lru_cache(maxsize=None)
def lobe_table(brdf: str) -> LobeTable:
    """The sigma -> (alpha, k) table of `brdf`, computed once per process (about a second)."""
    rows = np.array([match_lobe(brdf, float(s)) for s in TABLE_SIGMA])
    return LobeTable(brdf, TABLE_SIGMA.copy(), rows[:, 0], rows[:, 1], rows[:, 2])


def _specular_split(ps: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(specular strength, colour texture t) for Ps (H, W, C) and the gain per texel (H, W)."""
    ps = np.clip(np.asarray(ps, dtype=np.float64), 0.0, None)
    if ps.shape[-1] == 1:
        ps = np.repeat(ps, 3, axis=-1)
    top = ps.max(axis=-1)
    t = np.where(top[..., None] > 0, ps / np.maximum(top, 1e-300)[..., None], 1.0)
    return np.clip(level * top, 0.0, 1.0), t


def gltf_material(pd, ps, sigma, brdf: str, formula: str = "fitted") -> GltfMaterial:
    """glTF parameters of the fitted Pd (H, W, 3), Ps (H, W, C), sigma (H, W) under `brdf`: the fitted table
    (formula 'fitted') or the one-line formula ('one_line'); the lambertian BRDF gets no specular."""
    sigma = np.asarray(sigma, dtype=np.float64)
    if brdf == "lambertian":
        alpha, gain = np.ones_like(sigma), np.zeros_like(sigma)
    elif formula == "fitted":
        alpha, gain = lobe_table(brdf).lookup(sigma)
    elif formula == "one_line" and brdf == "torrance_sparrow":
        alpha, gain = np.minimum(math.sqrt(2.0) * sigma, 1.0), 8.0 * sigma * sigma
    elif formula == "one_line":
        alpha, gain = np.minimum(sigma, 1.0), np.ones_like(sigma)
    else:
        raise ValueError(f"formula {formula!r}: expected 'fitted' or 'one_line'")
    specular, t = _specular_split(ps, gain)
    return GltfMaterial(
        base_color=np.clip(np.asarray(pd, dtype=np.float64), 0.0, 1.0),
        roughness=np.sqrt(np.clip(alpha, 0.0, 1.0)),
        specular=specular,
        specular_color=t,
    )
