"""Rasterising a mesh's texture atlas into texels: which face and where on it each texel centre lies.

The atlas is a texture_size x texture_size grid S x S, stored like an image: row 0 at the top. Texel (row, col)
has its centre at uv = ((col + 0.5) / S, 1 - (row + 0.5) / S) (glTF / OBJ texture coordinates, v up), so a
parameter map written as an image with row 0 first lines up with the mesh's texture. In texel coordinates
x = u S, y = (1 - v) S the centre of texel (row, col) is (col + 0.5, row + 0.5).

A texel is surface when its centre lies in a face's UV triangle (on an edge counts); the rest is gutter. Texel
areas: the texel's UV area times the face's 3-D / UV area ratio (their sum estimates the mesh's area, as centre
sampling does). With `conservative`, a chart whose UV triangles hold no texel centre at all (a chart thinner than
a texel) still gets the gutter texels whose centre lies within half a texel of its faces, each placed at its
nearest face's point nearest the centre, and sharing the chart's 3-D area, so that no chart is lost. Charts that
have texel centres get no conservative texels: their border faces' area is already in the centre-sampled sum.

Two faces whose UV triangles both hold a texel centre strictly inside are overlapping charts (a mirrored or tiled
layout): an error, since one texel holds one reflectance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from torchrefl.errors import GeometryError
from torchrefl.geometry.atlas_charts import face_charts
from torchrefl.geometry.mesh_file import MeshData

# A texel centre this far (texels) inside two faces' UV triangles is covered twice: overlapping charts.
OVERLAP_DEPTH_TEXELS = 1e-3
# A centre this far (texels) outside a triangle still counts as on its edge.
EDGE_TOLERANCE_TEXELS = 1e-6
# Conservative texels: gutter texel centres within this distance (texels) of a chart with no texel centre.
CONSERVATIVE_REACH_TEXELS = 0.5
# Candidate (texel, face) pairs tested at once (memory bound of the rasteriser).
CHUNK_CANDIDATES = 1 << 22


@dataclass
class AtlasTexels:
    """The surface texels of an S x S atlas.

    texture_size: S. texel_index: (T,) int64 row * S + col, increasing. face: (T,) int64 face of each texel; chart:
    (T,) int64 its chart (atlas_charts.face_charts).
    barycentric: (T, 3) float64 weights of the face's corners at the texel centre (or, for a conservative texel,
    at the face's point nearest it). areas: (T,) float64 3-D area each texel stands for, in the mesh's units
    squared. conservative: (T,) bool, texels added by the conservative rule."""

    texture_size: int
    texel_index: np.ndarray
    face: np.ndarray
    chart: np.ndarray
    barycentric: np.ndarray
    areas: np.ndarray
    conservative: np.ndarray

    @property
    def num_texels(self) -> int:
        return int(len(self.texel_index))


def texel_uv(texel_index: np.ndarray, texture_size: int) -> np.ndarray:
    """(T, 2) uv of the centres of texels at flat indices texel_index (row * S + col) of an S x S atlas."""
    S = int(texture_size)
    rows, cols = np.divmod(np.asarray(texel_index, dtype=np.int64), S)
    return np.stack([(cols + 0.5) / S, 1.0 - (rows + 0.5) / S], axis=1)


def uv_to_texel_xy(uv: np.ndarray, texture_size: int) -> np.ndarray:
    """(..., 2) texel coordinates (x, y) = (u S, (1 - v) S) of uv (..., 2): texel (row, col) spans
    [col, col + 1) x [row, row + 1)."""
    uv = np.asarray(uv, dtype=np.float64)
    return np.stack([uv[..., 0] * texture_size, (1.0 - uv[..., 1]) * texture_size], axis=-1)


def _candidates(lo: np.ndarray, hi: np.ndarray, faces: np.ndarray, S: int):
    """(face, row, col) of every texel whose centre lies in the boxes [lo, hi] (F, 2) (x, y) of faces, chunked."""
    c0 = np.clip(np.ceil(lo[:, 0] - 0.5), 0, S).astype(np.int64)
    c1 = np.clip(np.floor(hi[:, 0] - 0.5), -1, S - 1).astype(np.int64)
    r0 = np.clip(np.ceil(lo[:, 1] - 0.5), 0, S).astype(np.int64)
    r1 = np.clip(np.floor(hi[:, 1] - 0.5), -1, S - 1).astype(np.int64)
    w, h = np.maximum(c1 - c0 + 1, 0), np.maximum(r1 - r0 + 1, 0)
    count = w * h
    ends = np.cumsum(count)
    start = 0
    while start < len(faces):
        stop = max(int(np.searchsorted(ends, ends[start] - count[start] + CHUNK_CANDIDATES, side="right")), start + 1)
        sel = np.arange(start, min(stop, len(faces)))
        n = count[sel]
        which = np.repeat(sel, n)
        k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        yield faces[which], r0[which] + k // w[which], c0[which] + k % w[which]
        start = sel[-1] + 1


class _Triangles:
    """Per-face constants of the UV triangles xy (F, 3, 2) for barycentric tests of many points."""

    def __init__(self, xy: np.ndarray):
        self.p0 = xy[:, 0]
        self.e1, self.e2 = xy[:, 1] - xy[:, 0], xy[:, 2] - xy[:, 0]
        det = self.e1[:, 0] * self.e2[:, 1] - self.e1[:, 1] * self.e2[:, 0]
        self.inv_det = 1.0 / np.where(det != 0, det, np.inf)
        opposite = np.stack([xy[:, 2] - xy[:, 1], xy[:, 0] - xy[:, 2], xy[:, 1] - xy[:, 0]], axis=1)
        # Distance to the edge opposite corner k per unit of barycentric k: the triangle's height there.
        self.height = np.abs(det)[:, None] / np.maximum(np.sqrt((opposite**2).sum(axis=2)), 1e-300)

    def barycentric(self, f: np.ndarray, p: np.ndarray):
        """Barycentric weights (M, 3) of points p (M, 2) in faces f (M,), and each point's signed distance (M, 3)
        to the line of the edge opposite each corner (positive inside)."""
        q = p - self.p0[f]
        e1, e2, inv = self.e1[f], self.e2[f], self.inv_det[f]
        b1 = (q[:, 0] * e2[:, 1] - q[:, 1] * e2[:, 0]) * inv
        b2 = (e1[:, 0] * q[:, 1] - e1[:, 1] * q[:, 0]) * inv
        bary = np.stack([1.0 - b1 - b2, b1, b2], axis=1)
        return bary, bary * self.height[f]


def _centre_hits(xy: np.ndarray, live: np.ndarray, S: int):
    """Every (texel, face, barycentric, depth) with the texel's centre in or on the face's triangle; depth is the
    centre's distance inside the nearest edge (texels)."""
    tri = _Triangles(xy)
    out = []
    for f, r, c in _candidates(xy[live].min(axis=1), xy[live].max(axis=1), live, S):
        p = np.stack([c + 0.5, r + 0.5], axis=1).astype(np.float64)
        bary, dist = tri.barycentric(f, p)
        depth = dist.min(axis=1)
        ok = depth >= -EDGE_TOLERANCE_TEXELS
        out.append((r[ok] * S + c[ok], f[ok], bary[ok], depth[ok]))
    if not out:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)
    return tuple(np.concatenate(parts) for parts in zip(*out))


def _check_overlap(texel, face, depth, source: str, S: int) -> None:
    deep = depth > OVERLAP_DEPTH_TEXELS
    t, f = texel[deep], face[deep]
    order = np.argsort(t, kind="stable")
    t, f = t[order], f[order]
    twice = np.flatnonzero(t[1:] == t[:-1])
    if len(twice):
        texels = np.unique(t[twice])
        faces = np.unique(np.concatenate([f[twice], f[twice + 1]]))
        row, col = divmod(int(t[twice[0]]), S)
        raise GeometryError(
            f"mesh file {source}: overlapping charts in the UV atlas: {len(texels)} texel centres of the {S}x{S} "
            f"atlas lie inside two or more faces ({len(faces)} faces overlap; e.g. faces {int(f[twice[0]])} and "
            f"{int(f[twice[0] + 1])} at texel row {row}, col {col}). Each texel holds one reflectance, so a "
            "mirrored or tiled UV layout cannot be used: re-unwrap the mesh or remove its UVs to get a new atlas"
        )


def _nearest_on_triangle(P: np.ndarray, p: np.ndarray):
    """Barycentric weights (M, 3) of the point of the boundary of triangles P (M, 3, 2) nearest p (M, 2), and
    its distance (M,)."""
    best_d = np.full(len(p), np.inf)
    best_b = np.zeros((len(p), 3))
    for k in range(3):
        a, b = P[:, k], P[:, (k + 1) % 3]
        ab = b - a
        s = np.clip(np.einsum("mi,mi->m", p - a, ab) / np.maximum(np.einsum("mi,mi->m", ab, ab), 1e-300), 0, 1)
        d = np.linalg.norm(a + s[:, None] * ab - p, axis=1)
        better = d < best_d
        bary = np.zeros((len(p), 3))
        bary[:, k], bary[:, (k + 1) % 3] = 1 - s, s
        best_d, best_b = np.where(better, d, best_d), np.where(better[:, None], bary, best_b)
    return best_b, best_d


def _conservative(xy, lonely, taken, S, chart, chart_area):
    """Gutter texels (not in taken) within CONSERVATIVE_REACH_TEXELS of the faces `lonely` (the faces of charts
    without a texel centre): (texel, face, barycentric, area), each texel on its nearest face, each chart's 3-D
    area shared equally by its texels."""
    reach = CONSERVATIVE_REACH_TEXELS
    parts = []
    for f, r, c in _candidates(xy[lonely].min(axis=1) - reach, xy[lonely].max(axis=1) + reach, lonely, S):
        t = r * S + c
        free = ~np.isin(t, taken)
        p = np.stack([c + 0.5, r + 0.5], axis=1).astype(np.float64)[free]
        bary, dist = _nearest_on_triangle(xy[f[free]], p)
        ok = dist <= reach
        parts.append((t[free][ok], f[free][ok], bary[ok], dist[ok]))
    t, f, bary, dist = (np.concatenate(x) for x in zip(*parts))
    order = np.lexsort((dist, t))
    first = order[np.r_[True, t[order][1:] != t[order][:-1]]] if len(order) else order
    t, f, bary = t[first], f[first], bary[first]
    count = np.bincount(chart[f], minlength=len(chart_area))
    return t, f, bary, chart_area[chart[f]] / np.maximum(count[chart[f]], 1)


def rasterise_atlas(mesh: MeshData, texture_size: int, conservative: bool = True) -> AtlasTexels:
    """The surface texels of mesh's UV atlas at texture_size x texture_size (module docstring). Raises
    GeometryError naming the mesh's file when it has no UVs, overlapping charts or no texel at all."""
    if mesh.uvs is None:
        raise GeometryError(f"mesh file {mesh.source}: the mesh has no UVs (make an atlas with parametrise first)")
    S = int(texture_size)
    xy = uv_to_texel_xy(mesh.uvs, S)
    e1, e2 = xy[:, 1] - xy[:, 0], xy[:, 2] - xy[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])  # texels^2
    face_area = mesh.face_areas()
    live = np.flatnonzero(uv_area > 1e-12)
    texel, face, bary, depth = _centre_hits(xy, live, S)
    _check_overlap(texel, face, depth, mesh.source, S)
    # A centre on the edge between two faces: the face it is deeper inside.
    order = np.lexsort((-depth, texel))
    keep = order[np.r_[True, texel[order][1:] != texel[order][:-1]]] if len(order) else order
    texel, face, bary = texel[keep], face[keep], bary[keep]
    area = face_area[face] / uv_area[face]
    extra = np.zeros(len(texel), dtype=bool)
    chart = face_charts(mesh)
    chart_area = np.bincount(chart, weights=face_area)
    lonely = live[~np.isin(chart[live], chart[face])]
    if conservative and len(lonely):
        t2, f2, b2, a2 = _conservative(xy, lonely, texel, S, chart, chart_area)
        texel, face = np.r_[texel, t2], np.r_[face, f2]
        bary, area = np.concatenate([bary, b2]), np.r_[area, a2]
        extra = np.r_[extra, np.ones(len(t2), dtype=bool)]
    if not len(texel):
        raise GeometryError(f"mesh file {mesh.source}: no texel centre of the {S}x{S} atlas falls on the mesh's UVs")
    order = np.argsort(texel)
    return AtlasTexels(S, texel[order], face[order], chart[face[order]], bary[order], area[order], extra[order])
