"""Faces split into smaller triangles, each remembering where it lies on its face."""

from __future__ import annotations

import numpy as np
import trimesh

#: halvings of the longest edges before subdivide_to_size gives up (2^30 pieces per edge: never reached in practice)
MAX_HALVINGS = 30


def split_faces(vertices: np.ndarray, faces: np.ndarray, max_edge: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The faces (F, 3) of vertices (V, 3) split until no edge is longer than max_edge (trimesh.remesh.
    subdivide_to_size; faces already that small are kept whole): (corners (E, 3, 3) float64 of the E triangles,
    parent (E,) int64 the face each lies on, bary (E, 3, 3) float64 the barycentric weights on the parent face of
    each triangle's corners: corner j = sum_k bary[e, j, k] vertices[faces[parent[e], k]])."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    sv, sf, parent = trimesh.remesh.subdivide_to_size(v, f, max_edge, max_iter=MAX_HALVINGS, return_index=True)
    corners = np.asarray(sv, dtype=np.float64)[np.asarray(sf, dtype=np.int64)]
    parent = np.asarray(parent, dtype=np.int64)
    tri = v[f[parent]]  # (E, 3, 3) the parent faces
    bary = trimesh.triangles.points_to_barycentric(np.repeat(tri, 3, axis=0), corners.reshape(-1, 3))
    return corners, parent, bary.reshape(-1, 3, 3)
