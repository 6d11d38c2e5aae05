"""Boundary texels of a triangulated range image: the silhouette, holes and depth discontinuities."""

import numpy as np

from torchrefl.geometry.range_mesh import boundary_texels, grid_triangulation


def grid(H=10, W=12, jump_col=None):
    r, c = np.meshgrid(np.arange(H, dtype=float), np.arange(W, dtype=float), indexing="ij")
    z = np.zeros_like(r)
    if jump_col is not None:
        z[:, jump_col:] = 100.0                      # a depth step between two columns
    return np.stack([c, r, z], -1)


def test_the_silhouette_is_the_boundary():
    pts = grid()
    valid = np.ones(pts.shape[:2], bool)
    valid[4:6, 5:7] = False                          # a hole
    _, faces = grid_triangulation(pts, valid)
    idx = np.flatnonzero(valid.ravel())
    edge = boundary_texels(faces, valid.shape, idx, 1)
    grid_edge = np.zeros(valid.size, bool)
    grid_edge[idx] = edge
    grid_edge = grid_edge.reshape(valid.shape)
    assert grid_edge[0].all() and grid_edge[-1].all() and grid_edge[:, 0].all() and grid_edge[:, -1].all()
    assert grid_edge[3, 5] and grid_edge[6, 6] and grid_edge[4, 4]     # around the hole
    assert not grid_edge[2, 2] and not grid_edge[8, 9]                  # interior
    assert not boundary_texels(faces, valid.shape, idx, 0).any()


def test_a_depth_discontinuity_is_a_boundary_and_width_dilates():
    pts = grid(jump_col=6)
    valid = np.ones(pts.shape[:2], bool)
    _, faces = grid_triangulation(pts, valid)
    idx = np.arange(valid.size)
    one = boundary_texels(faces, valid.shape, idx, 1).reshape(valid.shape)
    two = boundary_texels(faces, valid.shape, idx, 2).reshape(valid.shape)
    assert one[5, 5] and one[5, 6] and not one[5, 4] and not one[5, 7]
    assert two[5, 4] and two[5, 7] and not two[5, 3]
    assert (two >= one).all()
