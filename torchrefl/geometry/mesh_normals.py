"""Normals of a triangle mesh per face corner: smooth across UV seams, sharp at creases."""

from __future__ import annotations

import numpy as np

# Faces meeting at a vertex at more than this angle (degrees) do not smooth each other's normals (a crease).
DEFAULT_CREASE_ANGLE_DEG = 60.0


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of faces (F, 3) by their winding (right hand); zeros for a degenerate face."""
    v = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 0, n / np.maximum(length, 1e-300), 0.0)


def row_ids(*columns: np.ndarray) -> np.ndarray:
    """(N,) int64 id, 0.., shared by the rows equal in every one of the integer columns (N,) (a fast
    np.unique(axis=0) inverse: the columns are folded into one key a column at a time)."""
    ids = np.zeros(len(columns[0]), dtype=np.int64)
    for col in columns:
        col = np.unique(np.asarray(col, dtype=np.int64), return_inverse=True)[1].reshape(-1)
        ids = np.unique(ids * (int(col.max(initial=0)) + 1) + col, return_inverse=True)[1].reshape(-1)
    return ids


def welded_vertices(vertices: np.ndarray, tolerance: float = 1e-9) -> np.ndarray:
    """(V,) int64 id shared by vertices at the same position (within tolerance times the mesh's extent): the
    copies a loader makes at UV seams."""
    v = np.asarray(vertices, dtype=np.float64)
    if not len(v):
        return np.zeros(0, dtype=np.int64)
    q = np.round((v - v.min(axis=0)) / max(float(np.ptp(v, axis=0).max()) * tolerance, 1e-300)).astype(np.int64)
    return row_ids(q[:, 0], q[:, 1], q[:, 2])


def _corner_angles(v: np.ndarray) -> np.ndarray:
    """(F, 3) interior angle at each corner of triangles v (F, 3, 3)."""
    out = np.empty(v.shape[:2])
    for k in range(3):
        a = v[:, (k + 1) % 3] - v[:, k]
        b = v[:, (k + 2) % 3] - v[:, k]
        out[:, k] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("fi,fi->f", a, b))
    return out


def corner_normals(
    vertices: np.ndarray, faces: np.ndarray, crease_angle_deg: float = DEFAULT_CREASE_ANGLE_DEG
) -> np.ndarray:
    """(F, 3, 3) unit normal at each corner of faces (F, 3): the corner-angle-weighted mean of the normals of the
    faces around the corner's position (vertices at one position are one vertex, so UV seams do not show) whose
    normal is within crease_angle_deg of this face's (a cube keeps its flat faces, a sphere is smooth); a degenerate
    face's corners take every face around them (a UV sphere's poles). A corner whose sum vanishes keeps its face's
    normal."""
    v = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    fn = face_normals(v, faces)
    weight = _corner_angles(v[faces]).reshape(-1)
    key = welded_vertices(v)[faces].reshape(-1)
    normal = np.repeat(fn, 3, axis=0)
    # Corners grouped by position; each corner sums the qualifying corners of its group. Corners are visited in
    # order of their group's size so that pass j touches only the prefix of corners whose group has more than j.
    order = np.argsort(key, kind="stable")
    k_sorted = key[order]
    start_flag = np.r_[True, k_sorted[1:] != k_sorted[:-1]]
    group_start = np.maximum.accumulate(np.where(start_flag, np.arange(len(order)), 0))
    sizes = np.diff(np.r_[np.flatnonzero(start_flag), len(order)])
    group_size = np.repeat(sizes, sizes)
    by_size = np.argsort(-group_size, kind="stable")
    descending = -group_size[by_size]
    cos_crease = np.cos(np.radians(crease_angle_deg))
    total = np.zeros_like(normal)
    for j in range(int(sizes.max()) if len(sizes) else 0):
        pos = by_size[: np.searchsorted(descending, -j, side="left")]
        me, other = order[pos], order[group_start[pos] + j]
        mine = normal[me]
        ok = (np.einsum("ci,ci->c", mine, normal[other]) >= cos_crease) | ~mine.any(axis=1)
        total[me[ok]] += weight[other[ok], None] * normal[other[ok]]  # each corner once per pass
    length = np.linalg.norm(total, axis=1, keepdims=True)
    out = np.where(length > 1e-12, total / np.maximum(length, 1e-300), normal)
    return out.reshape(-1, 3, 3)
