"""The scan's TexelHits (core/texel_hits.py): hits on the range mesh, whose vertex k is grid point k.

A point of a face goes to the face corner with the largest barycentric weight (the first on a tie): the texel at
that grid point, whose collection area is one third of the area of the faces around its vertex (barycentric
regions are a third each), counting only faces whose normal agrees with the texel's (cos > COLLECT_COS): a face
cutting across a fold still scatters photons but does not count towards the fold texels' densities. A ray
(seen_texels) that meets a face bridging a fold or crease goes to the corner that faces it (fold_hits). Face
normals are turned to the side the sum of their corners' texel normals points to (the grid's winding may face
either way).
"""

from __future__ import annotations

import numpy as np

from torchrefl.errors import GeometryError
from torchrefl.geometry.range_mesh import oriented_face_normals
from torchrefl.transport.fold_hits import facing_corner, mixed_faces

#: a face corner collects photons for its texel when their normals agree this well
COLLECT_COS = 0.9


class RangeMeshHits:
    """TexelHits of a range mesh: vertices (V, 3) and faces (F, 3) of the texel grid's triangulation (vertex v is
    grid point v), texel_index (T,) the grid point of each texel, normals (T, 3) unit texel normals. Raises
    GeometryError when a texel is no mesh vertex or a face uses a grid point that is no texel.

    vertex_texel (V,) int64: the texel at each vertex (-1: none); collects (F, 3) bool: each face corner collects
    photons for its texel."""

    def __init__(self, vertices, faces, texel_index, normals):
        verts = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        texel_index = np.asarray(texel_index, dtype=np.int64)
        self.normals = np.ascontiguousarray(normals, dtype=np.float64)
        V = len(verts)
        if texel_index.size and texel_index.max() >= V:
            raise GeometryError(
                f"range mesh hits: texel grid index {int(texel_index.max())} is not a mesh vertex "
                f"(the mesh has {V}); the mesh must be the texel grid's triangulation"
            )
        self.vertex_texel = np.full(V, -1, dtype=np.int64)
        self.vertex_texel[texel_index] = np.arange(len(texel_index))
        if faces.size and (self.vertex_texel[faces] < 0).any():
            raise GeometryError("range mesh hits: some mesh faces use grid points that are not texels")
        corner_texel = self.vertex_texel[faces]  # (F, 3)
        self.face_normals = oriented_face_normals(verts, faces, self.normals[corner_texel])
        fa = (
            0.5
            * np.linalg.norm(
                np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]), axis=1
            )
            if faces.size
            else np.zeros(0)
        )
        # a face's corner collects for its texel only where the face lies along the texel's surface (normals within
        # ~25 deg): faces across a fold scatter photons but do not average the crease strip's irradiance in
        self.collects = np.einsum("fi,fci->fc", self.face_normals, self.normals[corner_texel]) > COLLECT_COS
        self.areas = np.bincount(
            corner_texel.ravel(),
            weights=(np.repeat(fa[:, None] / 3.0, 3, 1) * self.collects).ravel(),
            minlength=len(texel_index),
        ).astype(np.float64)
        self._corner_texel = corner_texel.astype(np.int32).ravel()
        self._corner_collects = self.collects.ravel()
        # faces whose corners' texel normals disagree (they bridge a fold or a crease): seen_texels' corner rule
        self._mixed_face = mixed_faces(self.normals[corner_texel]) if faces.size else np.zeros(0, dtype=bool)
        self._num_faces = len(faces)

    @property
    def num_texels(self) -> int:
        return int(len(self.normals))

    @property
    def num_faces(self) -> int:
        return self._num_faces

    def texels(self, face: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) int32 texel at the corner of each point's face with the largest weight bary (3, N) (the first on a
        tie), and (N,) bool whether that corner collects."""
        i = np.asarray(face).astype(np.int64) * 3 + np.asarray(bary).argmax(0)
        return np.take(self._corner_texel, i), np.take(self._corner_collects, i)

    def seen_texels(self, face: np.ndarray, bary: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """texels, except that on a face that bridges a fold or crease a ray along direction (3, N) goes to the
        corner that faces it (fold_hits.facing_corner, scored by barycentric weight)."""
        face = np.asarray(face).astype(np.int64)
        bary = np.asarray(bary)
        corner = bary.argmax(0)
        if face.size:
            m = np.flatnonzero(np.take(self._mixed_face, face))
            if m.size:
                texels = self._corner_texel[face[m][:, None] * 3 + np.arange(3)]  # (M, 3)
                corner[m] = facing_corner(corner[m], self.normals[texels], np.asarray(direction)[:, m].T, bary[:, m].T)
        i = face * 3 + corner
        return np.take(self._corner_texel, i), np.take(self._corner_collects, i)
