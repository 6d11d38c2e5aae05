"""Prediction at the photon level (Method III): local direct light plus the cached indirect light.

The cache holds, for every light p and texel t, what the photons stored there (second and later
bounces, torchrefl.transport.photon_trace) bring:
    H_pt   = sum_k Phi_k w_k u_k / A_t                          indirect irradiance (P, T, 3)
    entries (p, t, theta_h, c): the photons' incident directions reduced to what the specular lobe
           needs: theta_h = angle(n_t, half(wi_k, v_pt)) and c = Phi_k w_k / A_t * G(cos_i, cos_v) / cos_i,
           merged over photons of the same (p, t) whose theta_h falls in the same bin (power-weighted
           mean theta_h; bins max(0.004 rad, sigma_t / 4) wide for the texel's current roughness sigma_t:
           within 1 % of the unmerged sum, 3 % if the fit halves sigma before the next refresh), kept only
           for fitted or evaluated observations and where the lobe at the texel's current roughness
           (times 3, capped at sigma_max) is above 1e-7.
w_k are the light-map weights (torchrefl.transport.light_maps), u_k the hit's density weight
(PhotonHits.density_weight: irradiance on the texel's normal; Phi_k below stands for Phi_k u_k). H is kept
linear in the Pd of the texel each photon was last scattered from (its emitter e_k): the part of Phi_k that the
emitter's diffuse reflection carries is exactly proportional to Pd_e at that bounce, so
    H_pt(Pd) = H0_pt + sum_k L_k Pd_{e_k},   L_k = Phi_k^diffuse-per-unit-Pd w_k / A_t
(a sparse (light, texel) x texel matrix per channel), which makes the last bounce exact and
differentiable in the emitters' Pd between refreshes; earlier bounces stay as traced. The reflected
indirect light is differentiable in the receiving texel's parameters and in the emitters' Pd:
    i_ind(p, t) = kappa * ( Pd_t / pi * H_pt(Pd) + Ps_t * sum_entries D(theta_h; sigma_t) c )
the photon estimate of kappa * sum_k f_t(wi_k, v_pt) Phi_k / A_t with f = g / cos_i (torchrefl.core.brdf).
Photons reaching the texel at n.wi <= min_cos_light feed H but not the specular sum (the fitter
does not use grazing light either).

torchrefl.transport.cache_build builds the cache from the hits (and describes its density estimation);
torchrefl.transport.light_maps places the light maps of moving lights.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from torchrefl.core import brdf as brdf_mod
from torchrefl.transport.light_maps import LightSources
from torchrefl.transport.photon_density import apply_on_grid
from torchrefl.transport.photon_hits import PhotonHits
from torchrefl.transport.texel_model import SpecularEntries


@dataclass
class PhotonCache:
    """irradiance (P, T, 3) H0 (smoothed); entry_obs (E,) flat p*T + t; entry_theta_h (E,); entry_weight (E, 3);
    linear: sparse (3 P T, 3 T) L, rows c P T + p T + t, columns c T + e, or None; smoother: the
    density-estimation kernel (smoothing_matrix) applied to L Pd, or None (H0 is stored smoothed; None without
    linear); exact_irradiance:
    the part of H0 without photon noise (the radiosity level's all-diffuse paths, photon.diffuse_paths: radiosity),
    or None."""

    brdf: str
    irradiance: torch.Tensor
    entry_obs: torch.Tensor
    entry_theta_h: torch.Tensor
    entry_weight: torch.Tensor
    stats: dict = field(default_factory=dict)
    linear: torch.Tensor | None = None
    smoother: torch.Tensor | None = None
    exact_irradiance: torch.Tensor | None = None

    def to(self, dtype: torch.dtype, device=None) -> "PhotonCache":
        mv = lambda x: x.to(device=device, dtype=dtype if x.is_floating_point() else x.dtype)
        return PhotonCache(
            self.brdf,
            mv(self.irradiance),
            mv(self.entry_obs),
            mv(self.entry_theta_h),
            mv(self.entry_weight),
            dict(self.stats),
            None if self.linear is None else mv(self.linear),
            None if self.smoother is None else mv(self.smoother),
            None if self.exact_irradiance is None else mv(self.exact_irradiance),
        )

    def irradiance_at(self, pd: torch.Tensor) -> torch.Tensor:
        """(P, T, 3) H(Pd) for texel Pd (T, 3)."""
        if self.linear is None:
            return self.irradiance
        P, T, _ = self.irradiance.shape
        lin = torch.sparse.mm(self.linear, pd.t().reshape(-1, 1).to(self.irradiance.dtype))
        lin = lin.reshape(3, P, T).permute(1, 2, 0)
        if self.smoother is not None:
            lin = apply_on_grid(self.smoother, lin)
        return self.irradiance + lin


def indirect_radiance(
    cache: PhotonCache, kappa: torch.Tensor, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor
) -> torch.Tensor:
    """(P, T, 3) sensor value of the reflected indirect light for pd (T, 3), ps (T, C), sigma (T,);
    differentiable in all three."""
    H = cache.irradiance_at(pd)
    T = H.shape[1]
    out = (pd[None] / math.pi) * H
    if cache.entry_obs.numel():
        # index_select, not sigma[t]: the backward of advanced indexing (index_put_ with accumulate) sums the
        # entries' gradients in a thread-dependent order on CPU, which made fits differ from run to run
        out = out + ps[None] * _specular_sum(cache, sigma.index_select(0, cache.entry_obs % T))
    return kappa * out


def _specular_sum(cache: PhotonCache, entry_sigma: torch.Tensor) -> torch.Tensor:
    """(P, T, 3) S: the specular entries' lobe-weighted sum per observation, each entry's lobe at entry_sigma
    (per entry, or one value for all); the cached specular light is kappa Ps S."""
    P, T, _ = cache.irradiance.shape
    D = brdf_mod.specular_lobe(cache.brdf, cache.entry_theta_h, entry_sigma)
    S = torch.zeros(P * T, 3, dtype=cache.irradiance.dtype, device=cache.irradiance.device)
    return S.index_add(0, cache.entry_obs, D[:, None] * cache.entry_weight).view(P, T, 3)


def specular_per_unit_ps(cache: PhotonCache, kappa: torch.Tensor, sigma) -> torch.Tensor:
    """(P, T, 3) the sensor value of the cached specular interreflection per unit Ps, every texel's lobe at sigma:
    one value (a float or a 0-d tensor) or one per texel ((T,) tensor); what indirect_radiance adds as
    ps * kappa * S."""
    if not cache.entry_obs.numel():
        return torch.zeros_like(cache.irradiance)
    sigma = torch.as_tensor(sigma, dtype=cache.irradiance.dtype, device=cache.irradiance.device)
    if sigma.dim():
        sigma = sigma.index_select(0, cache.entry_obs % cache.irradiance.shape[1])
    return kappa * _specular_sum(cache, sigma)


def texel_cache(cache: PhotonCache, texels: torch.Tensor) -> PhotonCache:
    """The cache of the texels (n,) long only: H0 (P, n, 3) and their specular entries, renumbered to them (what
    specular_per_unit_ps needs; no linear part: Pd's own term is irradiance_at's, evaluated on all texels)."""
    P, T, _ = cache.irradiance.shape
    texels = texels.to(cache.entry_obs.device)
    row = torch.full((T,), -1, dtype=torch.long, device=texels.device)
    row[texels] = torch.arange(len(texels), device=texels.device)
    of = row.index_select(0, cache.entry_obs % T)
    keep = (of >= 0).nonzero()[:, 0]
    return PhotonCache(
        cache.brdf,
        cache.irradiance.index_select(1, texels),
        (cache.entry_obs.index_select(0, keep) // T) * len(texels) + of.index_select(0, keep),
        cache.entry_theta_h.index_select(0, keep),
        cache.entry_weight.index_select(0, keep),
    )


def texel_entries(cache: PhotonCache, kappa: torch.Tensor, texels: torch.Tensor) -> SpecularEntries:
    """The cached specular light per unit Ps of the texels (n,) long as SpecularEntries (obs p * n + j, the weights
    times kappa): what specular_per_unit_ps(texel_cache(cache, texels), kappa, sigma) sums."""
    sub = texel_cache(cache, texels)
    return SpecularEntries(sub.entry_obs, sub.entry_theta_h, sub.entry_weight * kappa.to(sub.entry_weight))


def indirect_radiance_reference(
    hits: PhotonHits,
    sources: LightSources,
    areas,
    normals,
    view_dirs,
    brdf: str,
    kappa,
    pd,
    ps,
    sigma,
    min_cos_light: float,
) -> torch.Tensor:
    """The same estimate straight from the stored photons and brdf.brdf (slow, obvious; tests only):
    kappa * sum_k f_t(wi_k, v_pt) Phi_k w_k / A_t, with the specular part dropped at n.wi <= min_cos_light
    and where the texel faces away from the camera (the diffuse part counts every stored photon: it reached
    the surface, even where the texel's smoothed normal disagrees)."""
    P, K = sources.positions.shape[:2]
    T = pd.shape[0]
    out = torch.zeros(P, T, 3, dtype=pd.dtype)
    ps3 = ps.expand(T, 3)
    for i in range(hits.count):
        p, k, t = int(hits.source[i] // K), int(hits.source[i] % K), int(hits.texel[i])
        n = normals[t]
        v = view_dirs[p, t] if view_dirs.dim() == 3 else view_dirs[t]
        wi = torch.as_tensor(hits.direction[i], dtype=pd.dtype)
        cos_i = float(n @ wi)
        f = pd[t] / math.pi  # every stored photon reached the surface
        if cos_i > min_cos_light and float(n @ v) > 0:
            f = f + brdf_mod.brdf(brdf, n, wi, v, torch.zeros_like(pd[t]), ps3[t], sigma[t])
        w = 1.0 if hits.density_weight is None else float(hits.density_weight[i])
        out[p, t] += f * torch.as_tensor(hits.power[i] * w * sources.weights[k, t] / float(areas[t]), dtype=pd.dtype)
    return kappa * out
