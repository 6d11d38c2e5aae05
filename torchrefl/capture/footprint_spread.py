"""How far the half-angle offset spreads over the surface points an observation's pixel value averages (mesh_views).

The loader reads a texel's value as the mean of bilinear values at footprint samples (capture.views_sampling), and
each pixel integrates over its area: the value is a weighted mean over surface points around the texel centre,
whose covariance in texel steps is

    A^-1 (Cov(samples) + mean over samples of diag(f (1 - f)) + I / 12) A^-T

(A: pixels per texel step; a bilinear value at fractional offset f spreads f (1 - f) px^2 per axis, a pixel's box
1/12 px^2). Across that footprint the normal turns (normal_steps: the blended corner normals' derivative in texel
steps) and the half vector turns with the light and view directions, so the 2-D half-angle offset
d = h - (h . n) n varies by J = (I - n n^T) dh - (h . n) dn per texel step. Its covariance J Sigma J^T, split
along d and across it, is the spread core.lobe_spread averages the lobe over. The lobe's weight (the BRDF's
specular geometry factor times the falloff, G) varies across the footprint too: G(x) ~ G exp(g . x) tilts the
footprint's mean by Sigma g (g the gradient of ln G per texel step), which shifts d by J Sigma g; the change of
|d| is the third value. A specular lobe of sigma 0.1 rad on a texel whose normal turns 0.2 rad is otherwise read
as a wider, lower lobe (sigma biased up, Ps down).
"""

from __future__ import annotations

import numpy as np

from torchrefl.core.brdf import SPECULAR_GEOMETRY_EXPONENTS
from torchrefl.geometry.atlas import uv_to_texel_xy
from torchrefl.geometry.atlas_neighbours import face_jacobians
from torchrefl.geometry.mesh_normals import DEFAULT_CREASE_ANGLE_DEG, corner_normals

#: a pixel's box (its area) spreads 1/12 px^2 per axis
PIXEL_BOX_VAR = 1.0 / 12.0


def footprint_covariance(uv: np.ndarray, px: np.ndarray) -> np.ndarray:
    """(K, 2, 2) covariance in texel steps (column, row) of the surface points averaged by the mean of bilinear
    values at uv (K, M, 2) pixel positions (module doc); px (K, 2, 2) pixels per texel step (columns = steps).
    Zeros where px is singular (a texel without steps)."""
    f = uv - np.floor(uv)
    centred = uv - uv.mean(axis=1, keepdims=True)
    cov = np.einsum("kmi,kmj->kij", centred, centred) / uv.shape[1]
    cov += np.eye(2)[None] * (f * (1.0 - f)).mean(axis=1)[:, None, :]
    cov += np.eye(2)[None] * PIXEL_BOX_VAR
    det = px[:, 0, 0] * px[:, 1, 1] - px[:, 0, 1] * px[:, 1, 0]
    ok = np.abs(det) > 1e-12
    out = np.zeros_like(cov)
    inv = np.linalg.inv(px[ok])
    out[ok] = inv @ cov[ok] @ np.swapaxes(inv, 1, 2)
    return out


def normal_steps(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, size: int, face, barycentric) -> np.ndarray:
    """(T, 3, 2) derivative of the unit texel normal (the blend of its face's corner normals, as
    geometry.atlas_surface.texel_geometry makes it) per texel step (column, row), at texels on faces face (T,) with
    barycentric (T, 3), on an atlas of size^2 texels (uvs (V, 2) or (F, 3, 2) per corner)."""
    corner = corner_normals(vertices, faces, DEFAULT_CREASE_ANGLE_DEG)  # (F, 3, 3)
    F = len(faces)
    xy = uv_to_texel_xy(uvs, size)
    xy = xy if xy.ndim == 3 else xy[faces]
    jac = face_jacobians(corner.reshape(-1, 3), np.arange(3 * F).reshape(F, 3), xy)[face]  # d(blend)/d(step)
    blend = np.einsum("tk,tki->ti", barycentric, corner[face])
    length = np.maximum(np.linalg.norm(blend, axis=1), 1e-12)
    n = blend / length[:, None]
    tangential = jac - n[:, :, None] * np.einsum("ti,tij->tj", n, jac)[:, None, :]
    return tangential / length[:, None, None]


def _turn(d: np.ndarray, dist: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """(T, 3, 2) change of the unit directions d (T, 3) towards fixed points dist (T,) away, per texel step steps
    (T, 3, 2): -(I - d d^T) step / dist (0 where dist is infinite: a directional light)."""
    along = np.einsum("ti,tij->tj", d, steps)
    return -(steps - d[:, :, None] * along[:, None, :]) / dist[:, None, None]


def half_angle_spread(
    normals: np.ndarray,
    steps: np.ndarray,
    dnormal: np.ndarray,
    spread: np.ndarray,
    light_dir: np.ndarray,
    light_dist: np.ndarray,
    view_dir: np.ndarray,
    view_dist: np.ndarray,
    brdf: str = "torrance_sparrow",
) -> np.ndarray:
    """(T, 3) float32: the variance (radians^2) of the half-angle offset along it and across it, and the shift of
    its length (radians) by the specular weight's slope across the footprint (module doc), for texels with unit
    normals (T, 3), texel steps (T, 3, 2), normal steps dnormal (T, 3, 2) (normal_steps), footprint covariance
    spread (T, 2, 2) in texel steps, unit light and view directions (T, 3) and their distances (T,) (inf for a
    directional light); brdf names the specular geometry factor (core.brdf.SPECULAR_GEOMETRY_EXPONENTS)."""
    n, l, v = normals, light_dir, view_dir
    s = l + v
    norm = np.maximum(np.linalg.norm(s, axis=1), 1e-12)
    h = s / norm[:, None]
    dl, dv = _turn(l, light_dist, steps), _turn(v, view_dist, steps)
    turn = dl + dv
    dh = (turn - h[:, :, None] * np.einsum("ti,tij->tj", h, turn)[:, None, :]) / norm[:, None, None]
    hn = np.einsum("ti,ti->t", h, n)
    jac = dh - n[:, :, None] * np.einsum("ti,tij->tj", n, dh)[:, None, :] - hn[:, None, None] * dnormal
    cov = jac @ spread @ np.swapaxes(jac, 1, 2)  # (T, 3, 3)
    total = np.einsum("tii->t", cov)
    # the specular weight G falloff tilts the footprint's mean by spread grad(ln(G falloff)), per texel step
    ev, el = SPECULAR_GEOMETRY_EXPONENTS[brdf]
    cos_v, cos_l = (np.maximum(np.einsum("ti,ti->t", n, x), 1e-4) for x in (v, l))
    dcos_v = np.einsum("tij,ti->tj", dnormal, v) + np.einsum("ti,tij->tj", n, dv)
    dcos_l = np.einsum("tij,ti->tj", dnormal, l) + np.einsum("ti,tij->tj", n, dl)
    slope = ev * dcos_v / cos_v[:, None] + el * dcos_l / cos_l[:, None]
    slope += 2.0 * np.einsum("ti,tij->tj", l, steps) / light_dist[:, None]  # d ln(1 / dist^2)
    d = h - hn[:, None] * n
    shifted = d + np.einsum("tij,tjk,tk->ti", jac, spread, slope)
    length = np.linalg.norm(shifted, axis=1)
    dhat = shifted / np.maximum(length, 1e-300)[:, None]
    along = np.where(length > 1e-9, np.einsum("ti,tij,tj->t", dhat, cov, dhat), total / 2.0)
    along = np.clip(along, 0.0, total)
    shift = length - np.linalg.norm(d, axis=1)
    return np.stack([along, total - along, shift], axis=1).astype(np.float32)
