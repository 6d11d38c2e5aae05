"""Observations whose footprint a cast shadow's edge may cross, for every capture kind (the cylindrical scan and
mesh_views).

The shadow test traces one ray from each texel's centre (core.point_light), while a texel's value integrates a
footprint reaching half-way to its neighbours. A lit texel whose surface neighbour (Surface.neighbours: on a scan of
the full turn the first and last columns are neighbours, on an atlas the texel across a seam is one) on the same
face is in cast shadow has the shadow's edge within one texel spacing: its value reads anything between lit and
dark, so the loaders leave it out (on the fold at full size such observations were 0.4 % of the fitted ones and
47 % of the squared image residual at the true parameters; on the concave mesh_views bowl they were 19 of the 20
observations more than 5 DN below the model at the true maps).
"""

from __future__ import annotations

import numpy as np

from torchrefl.core.texel_neighbours import TexelNeighbours

#: grid neighbours whose unit normals' cosine is below this lie across a crease: a shadow edge there is the crease's
SAME_FACE_COS = 0.9
#: the neighbours a texel's footprint borders: one step along each texel axis
EDGE_OFFSETS = ((0, 1), (1, 0), (0, -1), (-1, 0))


def face_neighbours(neighbours: TexelNeighbours, normals: np.ndarray) -> np.ndarray:
    """(T, 4) int64 the texel one step along each of EDGE_OFFSETS from each texel when it lies on the same face
    (unit normals (T, 3) within SAME_FACE_COS), -1 elsewhere."""
    n = np.asarray(normals, dtype=np.float64)
    t = np.arange(neighbours.num_texels)
    out = np.full((len(t), len(EDGE_OFFSETS)), -1, dtype=np.int64)
    for k, (dy, dx) in enumerate(EDGE_OFFSETS):
        other = neighbours.neighbour(t, dy, dx)
        same = (other >= 0) & (np.einsum("ti,ti->t", n, n[np.maximum(other, 0)]) >= SAME_FACE_COS)
        out[same, k] = other[same]
    return out


def shadow_edge_observations(shadowed: np.ndarray, adjacent: np.ndarray) -> np.ndarray:
    """(..., T) bool: observations not in cast shadow (shadowed (..., T) bool) of texels with a face neighbour
    (adjacent: face_neighbours) that is."""
    shadowed = np.asarray(shadowed, dtype=bool)
    edge = np.zeros_like(shadowed)
    for k in range(adjacent.shape[1]):
        same = np.flatnonzero(adjacent[:, k] >= 0)
        edge[..., same] |= shadowed[..., adjacent[same, k]]
    return edge & ~shadowed


def with_adjacent(texels: np.ndarray, adjacent: np.ndarray) -> np.ndarray:
    """(T,) bool: the texels (T,) bool and their face neighbours (adjacent: face_neighbours): where a loader traces
    shadow rays so that every neighbour a seen texel's edge test reads is traced."""
    texels = np.asarray(texels, dtype=bool)
    out = texels.copy()
    rows, cols = np.nonzero(adjacent >= 0)
    hit = texels[rows]
    out[adjacent[rows[hit], cols[hit]]] = True
    return out
