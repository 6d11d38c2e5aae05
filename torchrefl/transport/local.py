"""Local transport (Method I): direct light from point or directional lights, with cast shadows.

The measured value of observation (p, t) in channel c is
    i = kappa_c * Y_pc * falloff_pt * vis_pt * g(n_t, l_pt, v_pt; Pd, Ps, sigma)
with g the cosine-weighted BRDF (torchrefl.core.brdf). The geometry is fixed during a fit,
so LocalTerms precomputes everything that does not depend on the parameters:
    i = Pd * A + Ps * D(theta_h; sigma) * B,
A = kappa Y falloff vis max(n.l,0)/pi and B = kappa Y falloff vis G(cos_l, cos_v); with a Minnaert
diffuse part (brdf.diffuse_term) A carries the factor (cos_l cos_v)^(k - 1) of the exponent k.
`predict` is the fast path; `render_reference` evaluates the BRDF function directly
and is what the fast path is tested against.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.observations import Observations


@dataclass
class LocalTerms:
    """Parameter-independent factors of the local model.

    theta_h: (P, T) half-angle, radians.
    cos_l, cos_v: (P, T) cosines with the normal.
    diffuse: (P, T, 3) factor A multiplying Pd.
    specular: (P, T, 3) factor B multiplying Ps * D(theta_h; sigma).
    diffuse_exponent: Minnaert's k built into `diffuse` (1 = Lambert).
    spread: (P, T, 3) the observations' footprint spread of the half-angle offset (Observations.lobe_spread), the
    lobe D averaged over it (core.lobe_spread); None: D at the texel centre.
    """

    brdf: str
    theta_h: torch.Tensor
    cos_l: torch.Tensor
    cos_v: torch.Tensor
    diffuse: torch.Tensor
    specular: torch.Tensor
    diffuse_exponent: float = 1.0
    spread: torch.Tensor | None = None

    @property
    def num_lights(self) -> int:
        return int(self.theta_h.shape[0])

    def subset(self, texels: torch.Tensor, images: torch.Tensor | None = None) -> "LocalTerms":
        """The terms of the texels (n,) long under the images (m,) long only (None: every image)."""

        def pick(x: torch.Tensor) -> torch.Tensor:
            x = x.index_select(1, texels.to(x.device))
            return x if images is None else x.index_select(0, images.to(x.device))

        return LocalTerms(
            self.brdf,
            pick(self.theta_h),
            pick(self.cos_l),
            pick(self.cos_v),
            pick(self.diffuse),
            pick(self.specular),
            self.diffuse_exponent,
            None if self.spread is None else pick(self.spread),
        )

    def texels(self, index: torch.Tensor) -> "LocalTerms":
        """The terms of the texels index (n,) long only (each texel's terms are its own: the model of a subset); these
        terms themselves, not a copy, where index is every texel in order."""
        T = int(self.theta_h.shape[1])
        if len(index) == T and bool((index.cpu() == torch.arange(T)).all()):
            return self
        return self.subset(index)


def light_scale(obs: Observations) -> torch.Tensor:
    """(P, T, 3) kappa * Y * falloff * unshadowed: the irradiance scale of each observation."""
    unshadowed = (~obs.shadowed).to(obs.falloff.dtype)
    return obs.kappa * obs.light_intensity[:, None, :] * (obs.falloff * unshadowed)[..., None]


def local_terms(brdf_name: str, normals: torch.Tensor, obs: Observations, diffuse_exponent: float = 1.0) -> LocalTerms:
    """Precompute LocalTerms for normals (T, 3) and the observations' light/view geometry
    (diffuse_exponent: Minnaert's k, 1 = Lambert)."""
    brdf_mod.check_brdf_name(brdf_name)
    n = normals.unsqueeze(0)
    l = obs.light_dir
    v = obs.view_dirs_full()
    cos_l = brdf_mod.dot(n, l)
    cos_v = brdf_mod.dot(n, v)
    theta_h = brdf_mod.half_angle(n, l, v)
    scale = light_scale(obs)
    diffuse = scale * brdf_mod.diffuse_term(cos_l, cos_v, float(diffuse_exponent))[..., None]
    specular = scale * brdf_mod.specular_geometry(brdf_name, cos_l, cos_v)[..., None]
    spread = obs.lobe_spread
    spread = None if spread is None else spread.to(theta_h.dtype)
    return LocalTerms(brdf_name, theta_h, cos_l, cos_v, diffuse, specular, float(diffuse_exponent), spread)


def predict(terms: LocalTerms, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """(P, T, 3) predicted intensities for pd (T, 3), ps (T, C) with C in {1, 3}, sigma (T,)."""
    lobe = brdf_mod.specular_lobe(terms.brdf, terms.theta_h, sigma.unsqueeze(0), terms.spread)
    return pd.unsqueeze(0) * terms.diffuse + ps.unsqueeze(0) * (lobe[..., None] * terms.specular)


def render_reference(
    brdf_name: str, normals, obs: Observations, pd, ps, sigma, diffuse_exponent: float = 1.0
) -> torch.Tensor:
    """(P, T, 3) the same prediction straight from brdf.cosine_weighted_brdf (slow, obvious)."""
    g = brdf_mod.cosine_weighted_brdf(
        brdf_name,
        normals.unsqueeze(0),
        obs.light_dir,
        obs.view_dirs_full(),
        pd.unsqueeze(0),
        ps.unsqueeze(0),
        sigma.unsqueeze(0),
        diffuse_exponent,
    )
    return light_scale(obs) * g
