"""Texels at the edge of a cast shadow, whose footprint may lie partly in the shadow (mesh_views).

The shadow test traces one ray from each texel's centre (core.point_light). A texel whose centre is lit while one of
its four surface neighbours (Surface.neighbours: across chart seams on an atlas) is in cast shadow has the shadow's
edge within one texel spacing of its centre, so the pixels its value averages may be partly in shadow: the value
falls anywhere between the lit and the shadowed one. Such an observation is left out of the image, as texels at
silhouettes are. (On the concave bowl, 19 of the 20 observations more than 5 DN below the model at the true maps
were such texels, docs/results/mesh_views.md.)
"""

from __future__ import annotations

import numpy as np

from torchrefl.core.texel_neighbours import TexelNeighbours

#: the surface neighbours a texel's footprint borders: one step along each texel axis
EDGE_OFFSETS = ((0, 1), (0, -1), (1, 0), (-1, 0))


def adjacent_texels(neighbours: TexelNeighbours) -> np.ndarray:
    """(T, 4) int64 the texel one step along each of EDGE_OFFSETS from each texel, -1 where there is none."""
    t = np.arange(neighbours.num_texels)
    return np.stack([neighbours.neighbour(t, dy, dx) for dy, dx in EDGE_OFFSETS], 1).astype(np.int64)


def with_adjacent(texels: np.ndarray, adjacent: np.ndarray) -> np.ndarray:
    """(T,) bool: the texels (T,) bool and the texels adjacent (adjacent_texels) to one of them."""
    texels = np.asarray(texels, dtype=bool)
    out = texels.copy()
    rows, cols = np.nonzero(adjacent >= 0)
    hit = texels[rows]
    out[adjacent[rows[hit], cols[hit]]] = True
    return out


def shadow_edge(lit: np.ndarray, shadowed: np.ndarray, adjacent: np.ndarray) -> np.ndarray:
    """(T,) bool: texels lit and not shadowed (lit, shadowed (T,) bool: core.point_light.PointLight's) with an
    adjacent texel (adjacent_texels) in cast shadow."""
    shadowed = np.asarray(shadowed, dtype=bool)
    dark = np.where(adjacent >= 0, shadowed[np.maximum(adjacent, 0)], False)
    return np.asarray(lit, dtype=bool) & ~shadowed & dark.any(1)
