"""Neighbours on an atlas: within charts like the grid, across chart seams over the shared 3-D edge."""

import numpy as np
import trimesh
from atlas_meshes import cube_atlas, uv_sphere

from torchrefl.core.texel_grid import TexelGrid
from torchrefl.geometry.atlas_surface import atlas_geometry
from torchrefl.geometry.mesh_file import MeshData

SIDE = 16


def cube():
    return atlas_geometry(cube_atlas(side_texels=SIDE, texel_mm=1.0), texture_size=64)


def test_cube_seams_join_texels_across_cube_edges():
    g = cube()
    nb, p = g.neighbours, g.surface.positions.numpy()
    # Closed surface: every texel has a neighbour in each of the four directions.
    assert (nb.step >= 0).all()
    e = nb.edges
    d = np.linalg.norm(p[e[:, 0]] - p[e[:, 1]], axis=1)
    seam = nb.chart[e[:, 0]] != nb.chart[e[:, 1]]
    # Within a face: one texel (1 mm) apart; across an edge: half a texel on each side, sqrt(0.5) mm.
    assert np.allclose(d[~seam], 1.0)
    assert np.allclose(d[seam], np.sqrt(0.5))
    # 12 cube edges of SIDE texels each, one pair per texel along each edge.
    assert seam.sum() == 12 * SIDE
    # Each texel has four distinct neighbours, so every adjacent pair appears once: 2 T pairs.
    assert len(e) == 2 * g.surface.num_texels
    assert len(np.unique(np.sort(e, axis=1), axis=0)) == len(e)
    assert (nb.pairs() == e).all()


def test_a_walk_round_the_cube_comes_back_through_turned_and_mirrored_charts():
    g = cube()
    nb, p = g.neighbours, g.surface.positions.numpy()
    t = np.arange(g.surface.num_texels)
    assert set(np.unique(nb.turn)) - {0}, "the layout turns charts at seams"
    for dy, dx in ((0, 4 * SIDE), (4 * SIDE, 0), (0, -4 * SIDE), (-4 * SIDE, 0)):
        assert (nb.neighbour(t, dy, dx) == t).all()
    # Half way round: the texel on the opposite face, at the same distance from the cube's centre on each axis.
    half = nb.neighbour(t, 0, 2 * SIDE)
    centre = np.full(3, SIDE / 2)
    opposite = np.abs(p[half] - centre)
    assert np.allclose(opposite, np.abs(p - centre))
    # Any short offset stays within its length (in texels = mm) of the start, seams or not.
    for dy, dx in ((0, 3), (2, -2), (-5, 1)):
        o = nb.neighbour(t, dy, dx)
        assert (o >= 0).all()
        assert np.linalg.norm(p[o] - p, axis=1).max() <= abs(dy) + abs(dx) + 1e-9


def test_inside_a_chart_it_is_the_grid():
    g = atlas_geometry(cube_atlas(side_texels=SIDE), texture_size=64)
    nb = g.neighbours
    grid = TexelGrid(g.surface.texel_index.numpy(), g.surface.grid_shape)
    t = np.arange(g.surface.num_texels)
    for dy, dx in ((0, 1), (1, 0), (-1, -1), (2, 3)):
        ref = grid.neighbour(t, dy, dx)
        same = (ref >= 0) & (nb.chart[np.maximum(ref, 0)] == nb.chart)
        assert (nb.neighbour(t, dy, dx)[same] == ref[same]).all()
    assert (nb.at(nb.rows, nb.cols) == t).all()


def test_charts_side_by_side_in_uv_but_apart_in_3d_are_not_neighbours():
    # Two unit squares 100 mm apart whose UV charts touch along u = 0.5 (no gutter).
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64) * 8
    verts = np.concatenate([v, v + [100.0, 0, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    uv_left = np.array([[0, 0], [0.5, 0], [0.5, 1], [0, 1]])
    uv_right = uv_left + [0.5, 0]
    uvs = np.concatenate([uv_left[[[0, 1, 2], [0, 2, 3]]], uv_right[[[0, 1, 2], [0, 2, 3]]]])
    g = atlas_geometry(MeshData(verts, faces, uvs, source="two squares"), texture_size=16)
    nb, p = g.neighbours, g.surface.positions.numpy()
    e = nb.edges
    assert np.linalg.norm(p[e[:, 0]] - p[e[:, 1]], axis=1).max() <= 1.0 + 1e-9
    assert (nb.chart[e[:, 0]] == nb.chart[e[:, 1]]).all()
    # The squares' borders are mesh boundaries: steps off them find nothing.
    assert (nb.step < 0).any()


def test_xatlas_sphere_neighbours_stay_close():
    tm = trimesh.creation.icosphere(3, radius=10.0)
    g = atlas_geometry(MeshData(np.asarray(tm.vertices, float), np.asarray(tm.faces)), texture_size=128)
    nb, p = g.neighbours, g.surface.positions.numpy()
    size = np.sqrt(g.surface.areas.numpy())
    e = nb.edges
    d = np.linalg.norm(p[e[:, 0]] - p[e[:, 1]], axis=1) / np.minimum(size[e[:, 0]], size[e[:, 1]])
    seam = nb.chart[e[:, 0]] != nb.chart[e[:, 1]]
    assert seam.sum() > 100
    assert d.max() <= 2.1
    assert np.median(d[seam]) < 1.3
    assert (nb.step >= 0).mean() > 0.999


def test_uv_sphere_seam_joins_the_chart_to_itself():
    g = atlas_geometry(uv_sphere(10.0, 24, 48), texture_size=64)
    nb, p = g.neighbours, g.surface.positions.numpy()
    assert nb.chart.max() == 0
    # Texels in the first and last atlas columns sit on either side of the longitude seam.
    first = np.flatnonzero(nb.cols == 0)
    right_of_last = nb.neighbour(np.flatnonzero(nb.cols == 63), 0, 1)
    assert np.isin(right_of_last, first).mean() > 0.9
    size = 2 * np.pi * 10.0 / 64
    left = nb.neighbour(first, 0, -1)
    ok = left >= 0
    assert ok.mean() > 0.9
    assert np.linalg.norm(p[left[ok]] - p[first[ok]], axis=1).max() < 2 * size
