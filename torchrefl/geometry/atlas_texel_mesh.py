"""The texel mesh of an atlas: the triangle mesh the interreflection levels trace on a mesh_views capture.

The radiosity and photon levels (torchrefl.transport) map a ray's hit to a texel through the mesh's vertex layout
of the cylindrical scan: vertex k is grid point k of the texel grid, and a face belongs to the texel at its first
vertex (transport.patches.face_patches, transport.photon_trace). On an atlas, the same layout is the atlas grid's
triangulation (geometry.range_mesh.grid_triangulation of the texel centres), keeping only the quads whose four
texels lie in one chart, so that no triangle bridges two charts that sit side by side in UV only. It covers the
surface up to half a texel from each chart's border: along seams and the atlas's outline a crack about a texel
wide is left, through which the levels' rays can pass (an approximation until the levels map hits through the
atlas itself). The loader's own rays (visibility, shadows) use the real mesh.
"""

from __future__ import annotations

import numpy as np

from torchrefl.geometry.range_mesh import grid_triangulation


def texel_grid_mesh(
    texel_index: np.ndarray, chart: np.ndarray, positions: np.ndarray, grid_shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (H W, 3) float64, faces (F, 3) int64): the triangulation of the texel centres positions (T, 3) at
    texel_index (T,) on the (H, W) atlas grid, quads only within one chart (chart (T,) per texel)."""
    H, W = grid_shape
    valid = np.zeros(H * W, dtype=bool)
    valid[texel_index] = True
    points = np.zeros((H * W, 3))
    points[texel_index] = positions
    verts, faces = grid_triangulation(points.reshape(H, W, 3), valid.reshape(H, W), max_edge_ratio=np.inf)
    grid_chart = np.full(H * W, -1, dtype=np.int64)
    grid_chart[texel_index] = chart
    c = grid_chart[faces]
    return verts, faces[(c[:, 0] == c[:, 1]) & (c[:, 0] == c[:, 2])]
