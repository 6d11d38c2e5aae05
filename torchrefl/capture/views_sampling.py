"""What one calibrated camera sees of an atlas's texels, and the pixel values it records there (mesh_views).

For camera c with centre C and texel t at X with normal n, area a (side s = sqrt(a)):

- view direction v = (C - X) / |C - X|, cos_v = n . v; a texel facing away or seen at grazing view
  (cos_v <= the loader's min_cos_view) is not seen;
- visibility: Embree's first hit along the ray from C towards X must be the texel's own surface,
  | t_hit - |X - C| | < s + offset (offset: geometry.shadow_offset_mm);
- footprint: the texel is a parallelogram on the surface, spanned by the 3-D steps of one texel column and one
  texel row (the face's atlas Jacobian). The pixel value is the mean of bilinear interpolations (pixel centres at
  integer (u, v)) at m x m points spread over the part of the parallelogram whose pixels lie wholly inside the
  texel's projection: a bilinear value reaches SUPPORT_PX = 1.5 px (its farthest pixel, and that pixel's own
  area), so the samples keep that far from the texel's projected edges, and the value carries no neighbour's
  reflectance (a material border on a texel edge stays out of it). m is the inset part's projected length in
  pixels (at most MAX_SAMPLES), 1 (the centre) where that part is under a pixel across; a texel whose projection
  is narrower than NARROW_PX = 2.5 px along one of its steps is left out of the image (even its centre's value
  mixes its neighbours': the image does not resolve it; a closer or more frontal view may);
- slivers: at grazing view the two steps project nearly parallel, and a texel with edges longer than NARROW_PX
  may be far narrower across them (the parallelogram's width, projected_widths). Its value then averages the
  texels its support reaches across that width, which the footprint spread models where they continue its face;
  a sliver whose support reaches a texel off its face (none there, or a normal beyond SAME_FACE_COS: a crease, a
  rim, the mesh's border) is left out, as narrow. The footprint samples keep SUPPORT_PX from the edges across the
  width in every case;
- in frame: every sample lies within [0, W - 1] x [0, H - 1], so that its bilinear support is in the image;
- silhouettes and depth steps: rays from C through four points offset from X perpendicular to the view by
  (half the footprint + 1) pixels (the camera's x and y axes, both signs) must hit the texel's tangent plane
  where the plane predicts, within 2 (s + offset distance) + offset; a ray that misses the object (a
  silhouette) or meets a nearer or farther surface (an occluding edge, a rim) leaves the texel out of this
  camera's images, as edge texels are on the scan (mixed pixels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.capture.footprint_spread import footprint_covariance
from torchrefl.capture.shadow_edges import SAME_FACE_COS
from torchrefl.core.rays import RayTracer
from torchrefl.core.texel_neighbours import TexelNeighbours

#: at most this many footprint samples per texel side (a texel covering more pixels is averaged over 8 x 8)
MAX_SAMPLES = 8
#: how far (px) a bilinear sample's value reaches: one pixel to the farthest of its four pixels, plus half a pixel
#: that pixel integrates over
SUPPORT_PX = 1.5
#: a texel narrower than this (px) along one of its steps is left out of the image: its centre's four bilinear
#: pixels (SUPPORT_PX) reach past its edges by more than a quarter of a pixel, so its value mixes its neighbours'
NARROW_PX = 2.5
#: a sliver (narrower than NARROW_PX across its edges) whose value's support reaches more texel steps than this is
#: left out of the image
MAX_REACH = 8


@dataclass
class CameraView:
    """Texels as camera c sees them (T texels).

    view_dir: (T, 3) float32 unit vectors towards the camera; cos_v: (T,) float32 n . v.
    seen: (T,) bool, usable in this camera's images: in front, in frame, facing it, visible, no depth step.
    samples: [(texels (K,) int64, uv (K, m*m, 2) float64)] the footprint samples of the seen texels, grouped by m.
    reasons: {reason: (T,) bool} why texels are not seen (a texel counts under its first reason only).
    spread: (T, 2, 2) float64 covariance, in texel steps (column, row), of the surface points the footprint value
    averages (capture.footprint_spread.footprint_covariance); zeros at texels not seen."""

    view_dir: np.ndarray
    cos_v: np.ndarray
    seen: np.ndarray
    samples: list
    reasons: dict
    spread: np.ndarray


#: CameraView.reasons' names, in the order they are tested
OUTSIDE = "outside the image (or behind the camera)"
AWAY = "facing away from the camera or seen at grazing view (n.v at or below reflectance.min_cos_view)"
OCCLUDED = "occluded from the camera (the first hit is another surface)"
EDGE = "at a silhouette or depth step in the image (mixed pixels)"
SMALL = (
    f"narrower than {NARROW_PX:g} px in the image (its value mixes its neighbours'; capture.texture_size finer than "
    "the image)"
)
#: each reason's short name (metrics.json: capture.not_seen_<name>_observations)
REASON_KEYS = {OUTSIDE: "outside", AWAY: "facing_away", OCCLUDED: "occluded", SMALL: "narrow", EDGE: "silhouette"}


def _offsets(m: int) -> np.ndarray:
    """(m*m, 2) offsets in texel units of an m x m grid of sample points over a texel, centred."""
    o = (np.arange(m) + 0.5) / m - 0.5
    a, b = np.meshgrid(o, o, indexing="ij")
    return np.stack([a.ravel(), b.ravel()], -1)


def _in_frame(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """(...) bool: uv (..., 2) inside [0, W - 1] x [0, H - 1] (NaN: outside)."""
    with np.errstate(invalid="ignore"):
        return (uv[..., 0] >= 0) & (uv[..., 0] <= width - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= height - 1)


def camera_view(
    cameras,
    c: int,
    points: np.ndarray,
    normals: np.ndarray,
    areas: np.ndarray,
    steps: np.ndarray,
    tracer: RayTracer,
    *,
    offset: float,
    min_cos_view: float,
    neighbours: TexelNeighbours | None = None,
) -> CameraView:
    """CameraView of camera index c of `cameras` (capture.views_folder.Cameras: project, centres, K, R, width,
    height) for texels at points (T, 3) with unit normals (T, 3), areas (T,) and texel steps (T, 3, 2) (the 3-D
    displacement of one texel column and one texel row; zeros where unknown: centre sampling); neighbours: the
    surface's (Surface.neighbours) for the slivers' test (None: every sliver is left out)."""
    T = len(points)
    W, H = int(cameras.width[c]), int(cameras.height[c])
    C = cameras.centres()[c].numpy()
    fx, fy = float(cameras.K[c, 0, 0]), float(cameras.K[c, 1, 1])
    R = cameras.R[c].numpy()
    proj = cameras.project(torch.from_numpy(points), c)
    uv, z = proj.uv.numpy(), proj.depth.numpy()
    to_cam = C[None] - points
    d = np.linalg.norm(to_cam, axis=1)
    v = to_cam / np.maximum(d, 1e-300)[:, None]
    cos_v = np.einsum("ti,ti->t", normals, v)
    reasons = {}
    left = np.ones(T, dtype=bool)

    def drop(name: str, mask: np.ndarray) -> None:
        reasons[name] = left & mask
        left[mask] = False

    drop(OUTSIDE, ~((z > 0) & _in_frame(uv, W, H)))
    drop(AWAY, ~(cos_v > min_cos_view))
    side = np.sqrt(areas)
    idx = np.flatnonzero(left)
    if idx.size:
        hits = tracer.closest_hit(np.broadcast_to(C, (idx.size, 3)), -to_cam[idx])
        ok = hits.hit & (np.abs(hits.distance - d[idx]) < side[idx] + offset)
        occluded = np.zeros(T, dtype=bool)
        occluded[idx[~ok]] = True
        drop(OCCLUDED, occluded)
    # projected area in pixels (the depth-step offsets), and the part of the footprint whose pixels lie inside it
    zc = np.maximum(z, 1e-300)
    area_px = areas * np.maximum(cos_v, 0) * fx * fy * d / zc**3
    inset, m, narrow, px, width = _inset(points, steps, cameras, c, zc)
    sliver = left & ~narrow & steps.any(axis=(1, 2)) & (width < NARROW_PX).any(axis=1)
    idx = np.flatnonzero(sliver)
    narrow[idx] = _support_leaves_face(idx, width[idx], normals, neighbours)
    drop(SMALL, narrow)
    idx = np.flatnonzero(left)
    if idx.size:
        drop(EDGE, _depth_steps(idx, T, points, normals, side, np.sqrt(area_px), z, C, R, fx, tracer, offset))
    samples = []
    outside = np.zeros(T, dtype=bool)
    for k in np.unique(m[left]):
        idx = np.flatnonzero(left & (m == k))
        if k == 1:
            samples.append((idx, uv[idx, None, :]))
            continue
        offs = _offsets(int(k))[None] * inset[idx, None, :]  # (K, k*k, 2) texel units, inside the footprint
        pts = points[idx, None, :] + np.einsum("tij,tsj->tsi", steps[idx], offs)
        suv = cameras.project(torch.from_numpy(pts.reshape(-1, 3)), c).uv.numpy().reshape(len(idx), -1, 2)
        inside = _in_frame(suv, W, H).all(axis=1)
        outside[idx[~inside]] = True
        samples.append((idx[inside], suv[inside]))
    reasons[OUTSIDE] |= outside & left
    left &= ~outside
    spread = np.zeros((T, 2, 2))
    for idx, suv in samples:
        spread[idx] = footprint_covariance(suv, px[idx])
    spread[~left] = 0.0
    return CameraView(v.astype(np.float32), cos_v.astype(np.float32), left, samples, reasons, spread)


def _inset(points, steps, cameras, c: int, z) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(inset (T, 2), m (T,), narrow (T,) bool, px (T, 2, 2), width (T, 2)): the fraction of each texel step (column,
    row) that footprint samples may span so that every pixel their bilinear values use lies inside the texel's
    projection (SUPPORT_PX from each edge, across the projection's width), the samples per side (1: the centre only,
    where that part is under a pixel or the texel has no steps), the texels narrower than NARROW_PX along a step
    (even the centre's value mixes their neighbours'), the pixels per texel step (columns = steps) and the
    projection's width across each pair of edges (projected_widths)."""
    R = cameras.R[c].numpy()
    K = cameras.K[c].numpy()
    Xc = points @ R.T + cameras.t[c].numpy()
    J = np.zeros((len(points), 2, 3))  # d(u, v) / d(X_cam), pinhole (distortion ignored for the footprint's size)
    J[:, 0, 0] = K[0, 0] / z
    J[:, 0, 2] = -K[0, 0] * Xc[:, 0] / z**2
    J[:, 1, 1] = K[1, 1] / z
    J[:, 1, 2] = -K[1, 1] * Xc[:, 1] / z**2
    px = np.einsum("tij,jk,tkl->til", J, R, steps)  # (T, 2, 2): pixels per texel step, columns = steps
    length = np.linalg.norm(px, axis=1)  # (T, 2) projected length of each step, px
    width = projected_widths(px)
    with np.errstate(divide="ignore", invalid="ignore"):
        inset = np.clip(np.nan_to_num(1.0 - 2.0 * SUPPORT_PX / width), 0.0, 1.0)
    m = np.clip(np.ceil((inset * length).max(axis=1)), 1, MAX_SAMPLES).astype(np.int64)
    m[(inset * length).max(axis=1) <= 1.0] = 1
    narrow = steps.any(axis=(1, 2)) & (length < NARROW_PX).any(axis=1)
    return inset, m, narrow, px, width


def _support_leaves_face(idx: np.ndarray, width: np.ndarray, normals: np.ndarray, neighbours) -> np.ndarray:
    """(K,) bool: slivers idx (K,) (projected widths (K, 2) px, one under NARROW_PX) whose value's support reaches
    a texel off their face: along each narrow axis the support (SUPPORT_PX from the centre) touches the texels up
    to k = ceil(SUPPORT_PX / width + 1/2) - 1 steps away (at most MAX_REACH, beyond which the sliver is left out),
    each of which must exist and have its normal within SAME_FACE_COS of the sliver's. neighbours None: all."""
    out = np.ones(len(idx), dtype=bool)
    if neighbours is None or not len(idx):
        return out
    with np.errstate(divide="ignore"):
        reach = np.ceil(SUPPORT_PX / width + 0.5) - 1.0  # (K, 2) texel steps the support touches, per axis
    out = (reach > MAX_REACH).any(axis=1)
    n = normals[idx]
    for axis, (dy, dx) in enumerate(((0, 1), (1, 0))):  # width[:, 0] is across the column step: the next column
        narrow = width[:, axis] < NARROW_PX
        for k in range(1, MAX_REACH + 1):
            ask = np.flatnonzero(narrow & ~out & (reach[:, axis] >= k))
            if not len(ask):
                break
            for sign in (1, -1):
                other = neighbours.neighbour(idx[ask], sign * k * dy, sign * k * dx)
                cos = np.einsum("ti,ti->t", n[ask], normals[np.maximum(other, 0)])
                out[ask[(other < 0) | (cos < SAME_FACE_COS)]] = True
    return out


def projected_widths(px: np.ndarray) -> np.ndarray:
    """(T, 2) the projected texel's width (px) across each pair of its edges: for the parallelogram spanned by the
    steps' projections a, b (px (T, 2, 2), columns), |a x b| / |b| along a and |a x b| / |a| along b. This is the
    step's length where the projections are perpendicular, and far less at grazing view, where they turn towards
    one another and the parallelogram is a thin sliver between long edges."""
    a, b = px[..., 0], px[..., 1]
    area = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    length = np.linalg.norm(px, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.nan_to_num(area[:, None] / length[:, ::-1])


def _depth_steps(idx, T, points, normals, side, footprint_px, z, C, R, fx, tracer, offset) -> np.ndarray:
    """(T,) bool: texels idx whose neighbourhood in the image meets a depth step (module doc)."""
    X, n = points[idx], normals[idx]
    delta = (footprint_px[idx] / 2 + 1.0) * z[idx] / fx  # world offset of (half the footprint + 1) pixels
    step = np.zeros(len(idx), dtype=bool)
    plane = np.einsum("ti,ti->t", n, X - C[None])  # n . (X - C) < 0 for a texel facing the camera
    tol = 2.0 * (side[idx] + delta) + offset
    for axis in (0, 1):
        for sign in (1.0, -1.0):
            Y = X + (sign * delta)[:, None] * R[axis][None]
            r = Y - C[None]
            r /= np.linalg.norm(r, axis=1, keepdims=True)
            nr = np.einsum("ti,ti->t", n, r)
            hits = tracer.closest_hit(np.broadcast_to(C, r.shape), r)
            with np.errstate(divide="ignore", invalid="ignore"):
                expected = np.where(nr < 0, plane / nr, math.inf)
            step |= ~hits.hit | ~(np.abs(hits.distance - expected) < tol)
    out = np.zeros(T, dtype=bool)
    out[idx[step]] = True
    return out


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, C) values of image (H, W, C) at uv (N, 2) in [0, W - 1] x [0, H - 1] (pixel centres at integers)."""
    H, W = image.shape[:2]
    u = np.clip(uv[:, 0], 0, W - 1)
    v = np.clip(uv[:, 1], 0, H - 1)
    i0 = np.minimum(np.floor(u).astype(np.int64), max(W - 2, 0))
    j0 = np.minimum(np.floor(v).astype(np.int64), max(H - 2, 0))
    i1, j1 = np.minimum(i0 + 1, W - 1), np.minimum(j0 + 1, H - 1)
    a, b = (u - i0)[:, None], (v - j0)[:, None]
    return (image[j0, i0] * (1 - a) * (1 - b) + image[j0, i1] * a * (1 - b) + image[j1, i0] * (1 - a) * b) + image[
        j1, i1
    ] * a * b


def footprint_values(image: np.ndarray, view: CameraView, T: int) -> np.ndarray:
    """(T, C) float32 pixel values of image (H, W, C) at each seen texel's footprint (the mean of the bilinear
    values at its samples), NaN at texels this camera does not see."""
    out = np.full((T, image.shape[2]), np.nan, dtype=np.float32)
    for idx, uv in view.samples:
        if idx.size:
            vals = bilinear(image, uv.reshape(-1, 2)).reshape(len(idx), uv.shape[1], -1)
            out[idx] = vals.mean(axis=1)
    return out


#: warn when more than this share of the texels the images face is seen by no image yet was too narrow in one (an
#: atlas too fine; an atlas's smallest texels, e.g. near a UV sphere's poles, leave out 14-27 % on the bundled scenes)
NARROW_SHARE = 0.5


def narrow_warning(seen: np.ndarray, narrow: np.ndarray) -> list[str]:
    """A warning when more than NARROW_SHARE of the texels that some image faces and frames is seen by no image and
    narrower than NARROW_PX in some image (it would be seen, were the texels larger): capture.texture_size finer
    than the images resolve. seen, narrow (P, T) bool: each image's seen texels and those left out as narrow."""
    seen = seen.any(0)
    left_out = ~seen & narrow.any(0)
    n = int(left_out.sum())
    shown = n + int(seen.sum())  # the texels some image faces and frames (the rest no atlas size would show)
    if not shown or n <= NARROW_SHARE * shown:
        return []
    return [
        f"{n} of the {shown} texels the images face ({n / shown:.0%}) are seen by no image because they are narrower "
        f"than {NARROW_PX:g} px in them: capture.texture_size is finer than the images resolve (a coarser atlas, "
        "e.g. half the size, gives each texel 4x the pixels)"
    ]
