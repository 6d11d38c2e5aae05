"""Prediction at the radiosity level (Method II): local direct light plus diffuse interreflection.

For light p, texel t in patch u(t), channel c:
    E_t      = Y_p falloff vis max(n.l, 0)                 direct irradiance (LocalTerms.diffuse * pi / kappa)
    E_u      = area-weighted mean of E_t over u's texels
    rho_u    = min(area-weighted mean of Pd_t over u's texels, RHO_MAX)
    B        = solve_radiosity(rho, E, F)                   (torchrefl.transport.radiosity)
    H_t      = sum_v F_{u(t) v} B_v                         indirect irradiance at the texel
    i_pt     = local(t) + kappa Pd_t / pi * H_t
Moving lights. On a co-rotating rig texel t's image was taken with light p at its own position L_pt, and
then the whole object was lit from there: the emitters' E must come from L_pt too, not from the positions
their own columns saw. EmitterMaps holds E under K source positions per light (those of
photon_level.light_sources: evenly spaced columns, cubic weights over the four maps nearest to t's
column); B is solved for all P x K of them at once (one factorisation, more right-hand sides) and H_t
interpolates between the maps. Static lights need no maps (E from the local terms, with the capture's visibility).

RHO_MAX = 0.99 is the one clamp here: an uncalibrated or not yet converged Pd above 1 would make
I - rho F singular in closed geometry; Pd itself is not clamped (the direct term still sees it).
The specular reflection of direct light does not feed the interreflection and indirect light is
reflected diffusely only: that is what the radiosity level models (the photon level adds both).

Also the closed-form inverse radiosity (eq. 4.7 generalised to our direct term):
    rho_u = B_u / (E_u + sum_v F_uv B_v)
with the measured radiosity B_u = pi i / kappa of patches observed diffusely.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.core.distinct_rows import distinct_rows
from torchrefl.core.point_light import point_light
from torchrefl.transport.local import LocalTerms, predict
from torchrefl.transport.radiosity import _matmul, solve_radiosity

RHO_MAX = 0.99


@dataclass
class PatchMap:
    """texel_patch (T,) int64 patch of each texel (every texel belongs to one patch);
    areas (T,) texel areas; Q number of patches. Averages are area-weighted."""

    texel_patch: torch.Tensor
    areas: torch.Tensor
    num_patches: int

    def __post_init__(self):
        Q = self.num_patches
        w = self.areas.double()
        self._patch_area = torch.zeros(Q, dtype=torch.float64).index_add_(0, self.texel_patch, w)

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """Area-weighted patch means of texel values x (..., T, C) -> (..., Q, C)."""
        w = (self.areas.to(x.dtype) / self._patch_area.to(x.dtype)[self.texel_patch])[:, None]
        shape = x.shape[:-2] + (self.num_patches, x.shape[-1])
        out = torch.zeros(shape, dtype=x.dtype, device=x.device)
        return out.index_add_(-2, self.texel_patch, x * w)

    def scatter(self, y: torch.Tensor) -> torch.Tensor:
        """Patch values (..., Q, C) -> texel values (..., T, C)."""
        return y.index_select(-2, self.texel_patch)


def direct_irradiance(terms: LocalTerms, kappa: torch.Tensor, images: torch.Tensor | None = None) -> torch.Tensor:
    """(P, T, 3) Y falloff vis max(n.l, 0) from the local terms; images (R,) long: of those images only (R, T, 3)."""
    diffuse = terms.diffuse if images is None else terms.diffuse.index_select(0, images.to(terms.diffuse.device))
    return diffuse * (math.pi / kappa)


@dataclass
class EmitterMaps:
    """irradiance (P, K, T, 3): Y_p max(n_t.l, 0) vis / d^2 at every texel with light p at map k's source
    position; weights (K, T): each texel's weights over the maps (photon_level.map_weights; columns sum to one)."""

    irradiance: torch.Tensor
    weights: torch.Tensor


def emitter_maps(sources, positions: torch.Tensor, normals: torch.Tensor, tracer, offset: float) -> EmitterMaps:
    """EmitterMaps for photon_level.LightSources `sources` (positions (P, K, 3), weights (K, T), intensity
    (P, 3)): E = Y max(n.l, 0) vis / d^2 of light p at each map's source, from torchrefl.core.point_light (cast
    shadows by its shadow test: tracer, a RayTracer of the texel mesh; offset, the shadow ray's origin offset,
    the capture's geometry.shadow_offset_mm), in float64."""
    x = positions.detach().cpu().double().numpy()
    n = normals.detach().cpu().double().numpy()
    P, K = sources.positions.shape[:2]
    E = np.zeros((P, K, len(x), 3))
    for p in range(P):
        Y = np.asarray(sources.intensity[p], dtype=np.float64)
        for k in range(K):
            L = np.broadcast_to(np.asarray(sources.positions[p][k], dtype=np.float64), x.shape)
            E[p, k] = point_light(x, n, L, tracer, offset=offset).irradiance(Y)
    return EmitterMaps(torch.from_numpy(E), torch.as_tensor(np.asarray(sources.weights, dtype=np.float64)))


def indirect_irradiance(
    terms: LocalTerms,
    kappa,
    pd: torch.Tensor,
    patches: PatchMap,
    F: torch.Tensor,
    maps: EmitterMaps | None = None,
    F_solve: torch.Tensor | None = None,
    per_map: bool = False,
    reconstruct: torch.Tensor | None = None,
    emitters: "DistinctEmitters | None" = None,
    **solver,
) -> torch.Tensor:
    """(P, T, 3) diffuse interreflected irradiance H at every texel for texel Pd (T, 3); with maps, the
    emitters are lit from each map's source and H interpolates between maps (module doc). emitters (without
    maps): the images' distinct direct irradiances (distinct_emitters), solved once each and H copied to the images
    that share one (None = one solve per image). F_solve: other
    (cheaper, noisier) form factors of the same patches for the solve B = rho (E + F_solve B), F then only
    gathers H = F B (None = F for both): B's noise averages out over the many emitters a patch gathers from,
    while the gather's noise is what each texel sees. per_map: return (P, K, T, 3), H at every texel with
    the light at each map's source (K = 1 without maps), before the interpolation. reconstruct: a sparse (T, Q)
    operator from the patches' H to the texels' (patch_reconstruction.linear_reconstruction); None = each texel
    takes its patch's H."""
    rho = patches.mean(pd[None])[0].clamp(max=RHO_MAX)  # (Q, 3)
    if maps is None:
        images = None if emitters is None else emitters.first
        E = patches.mean(direct_irradiance(terms, kappa, images))  # (P or R, Q, 3)
    else:
        P, K, T, C = maps.irradiance.shape
        E = patches.mean(maps.irradiance.to(pd.dtype).reshape(P * K, T, C))  # (P K, Q, 3)
    B = solve_radiosity(rho, E, F if F_solve is None else F_solve, **solver)  # (P or P K, Q, 3)
    R, Q, C = B.shape
    H = _matmul(F, B.permute(1, 0, 2).reshape(Q, R * C))  # (Q, R C)
    if reconstruct is None:
        H = patches.scatter(H.reshape(Q, R, C).permute(1, 0, 2))  # (R, T, 3)
    else:
        H = _at_least_zero(_matmul(reconstruct, H), H, patches.texel_patch)
        H = H.reshape(H.shape[0], R, C).permute(1, 0, 2)
    if maps is None:
        if emitters is not None:
            H = H.index_select(0, emitters.inverse.to(H.device))  # (P, T, 3)
        return H[:, None] if per_map else H
    if per_map:
        return H.reshape(P, K, T, C)
    return (H.reshape(P, K, T, C) * maps.weights.to(H.dtype)[None, :, :, None]).sum(1)


@dataclass
class DistinctEmitters:
    """The images whose direct irradiance is the same (images of one light from several cameras): first (R,) long
    one image of each distinct irradiance, inverse (P,) long the distinct irradiance of each image."""

    first: torch.Tensor
    inverse: torch.Tensor

    @property
    def shared(self) -> bool:
        """Some images share their direct irradiance (fewer solves than images)."""
        return len(self.first) < len(self.inverse)


def distinct_emitters(terms: LocalTerms, kappa) -> DistinctEmitters:
    """The DistinctEmitters of the images of terms: equal when their direct irradiance over every texel is equal
    bit for bit (with a Lambertian diffuse term, the interreflection levels', an image's irradiance does not depend
    on its camera: every texel's, seen or not, is the light's; a camera-dependent term groups nothing)."""
    first, of = distinct_rows(direct_irradiance(terms, kappa).detach().cpu().numpy())
    return DistinctEmitters(torch.from_numpy(first).long(), torch.from_numpy(of).long())


def _at_least_zero(planes: torch.Tensor, patch_values: torch.Tensor, texel_patch: torch.Tensor) -> torch.Tensor:
    """Texel irradiance (T, R C) from the reconstruction's planes, where a plane goes below zero (it extrapolates noisy
    patches at a chart's edge when the form factors have few rays) the texel's own patch value (Q, R C) instead:
    irradiance is never negative, and the patch's is (F, B >= 0)."""
    negative = planes < 0
    if not bool(negative.any()):
        return planes
    own = patch_values.index_select(0, texel_patch.to(patch_values.device))
    return torch.where(negative, own, planes)


def reflected_indirect(kappa, pd: torch.Tensor, H: torch.Tensor) -> torch.Tensor:
    """(P, T, 3) the measured value of indirect irradiance H (P, T, 3) reflected diffusely: kappa Pd / pi * H."""
    return (kappa / math.pi) * pd[None].to(H.dtype) * H


def predict_radiosity(
    terms: LocalTerms, kappa, pd, ps, sigma, patches: PatchMap, F, maps: EmitterMaps | None = None, **solver
) -> torch.Tensor:
    """(P, T, 3) local prediction plus the diffusely reflected interreflection."""
    return predict(terms, pd, ps, sigma) + reflected_indirect(
        kappa, pd, indirect_irradiance(terms, kappa, pd, patches, F, maps, **solver)
    )


def inverse_radiosity(
    terms: LocalTerms, kappa, intensity: torch.Tensor, diffuse_mask: torch.Tensor, patches: PatchMap, F
) -> tuple[torch.Tensor, torch.Tensor]:
    """Closed-form patch reflectance from eq. 4.7, per light, combined over lights.

    intensity (P, T, 3); diffuse_mask (P, T) observations that carry diffuse light only (T_diff).
    B_u is the measured radiosity (pi i / kappa, area mean over the patch's diffuse texels);
    patches without a diffuse observation under a light take no part for that light, and their
    radiosity in the gather is the measured one where seen, else 0. Returns rho (Q, 3) and
    determined (Q,) bool.
    """
    dtype = intensity.dtype
    w = diffuse_mask.to(dtype)[..., None]
    B_meas = math.pi * intensity / kappa  # (P, T, 3)
    num = patches.mean(B_meas * w)
    cov = patches.mean(w.expand_as(B_meas).contiguous())  # fraction of the patch observed
    B_u = num / cov.clamp_min(1e-12)
    seen = cov[..., 0] > 0.5  # (P, Q)
    E = patches.mean(direct_irradiance(terms, kappa))
    P, Q, C = B_u.shape
    Bg = torch.where(seen[..., None], B_u, torch.zeros_like(B_u))
    FB = _matmul(F.to(dtype), Bg.permute(1, 0, 2).reshape(Q, P * C)).reshape(Q, P, C).permute(1, 0, 2)
    denom = E + FB
    # least squares over lights: rho = sum B denom / sum denom^2 over the lights that saw the patch
    m = seen[..., None].to(dtype)
    rho = (m * B_u * denom).sum(0) / (m * denom * denom).sum(0).clamp_min(1e-30)
    determined = seen.any(0)
    return torch.where(determined[:, None], rho, torch.zeros_like(rho)), determined
