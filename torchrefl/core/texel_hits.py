"""Which texel a point of the traced mesh belongs to: the one map behind every ray hit of the interreflection levels.

Each capture kind hands its Surface a TexelHits (Surface.hits), as it hands it its neighbours
(core/texel_neighbours.py): a mesh's atlas geometry/atlas_hits.AtlasHits (the real mesh is traced; a point's uv
gives its texel); the scan's range mesh (vertex k is grid point k) transport/range_mesh_hits.RangeMeshHits (a point
goes to the face corner nearest it; on a face that bridges a fold a ray goes to the corner that faces it), built
from the mesh when Surface.hits is None. The photon tracer's emission points, photon hits, collection areas and
front sides, the specular gather's rays and the radiosity level's form factors ask it, never the mesh's vertex
layout (on the range mesh the form factors keep their face-owner rule, transport/patches.face_patches: there a
face is one texel's).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class TexelHits(Protocol):
    """What the interreflection levels ask of the surface a ray meets.

    face_normals: (F, 3) float64 unit geometric normals of the traced mesh's faces, turned to the front (the side
    the texel normals face; zeros for a degenerate face). areas: (T,) float64 collection area of each texel, the
    area of mesh whose photon hits it collects (photon densities divide by it). num_texels T, num_faces F.
    Optional emission_size (scene units): where faces may be larger than texels (an atlas), photons land on the faces
    split to about this edge length (transport/photon_trace.py); without it, on the faces as they are."""

    face_normals: np.ndarray
    areas: np.ndarray

    @property
    def num_texels(self) -> int: ...

    @property
    def num_faces(self) -> int: ...

    def texels(self, face: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(texel (N,) int, collects (N,) bool) of the points of faces face (N,) at barycentric weights bary (3, N)
        of the faces' corners: the texel whose collection area holds each point, and whether a photon hit there
        counts in that texel's density."""

    def seen_texels(self, face: np.ndarray, bary: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Like texels, for rays arriving along direction (3, N): the texel each ray sees where it meets the
        surface."""
