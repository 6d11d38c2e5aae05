"""Boundary texels of a triangulated range image: the silhouette, holes and depth discontinuities; crease
texels: folds and rims."""

import numpy as np
import pytest

from torchrefl.errors import GeometryError
from torchrefl.geometry.range_mesh import boundary_texels, crease_texels, grid_triangulation, oriented_face_normals


def grid(H=10, W=12, jump_col=None):
    r, c = np.meshgrid(np.arange(H, dtype=float), np.arange(W, dtype=float), indexing="ij")
    z = np.zeros_like(r)
    if jump_col is not None:
        z[:, jump_col:] = 100.0  # a depth step between two columns
    return np.stack([c, r, z], -1)


def test_the_silhouette_is_the_boundary():
    pts = grid()
    valid = np.ones(pts.shape[:2], bool)
    valid[4:6, 5:7] = False  # a hole
    _, faces = grid_triangulation(pts, valid)
    idx = np.flatnonzero(valid.ravel())
    edge = boundary_texels(faces, valid.shape, idx, 1)
    grid_edge = np.zeros(valid.size, bool)
    grid_edge[idx] = edge
    grid_edge = grid_edge.reshape(valid.shape)
    assert grid_edge[0].all() and grid_edge[-1].all() and grid_edge[:, 0].all() and grid_edge[:, -1].all()
    assert grid_edge[3, 5] and grid_edge[6, 6] and grid_edge[4, 4]  # around the hole
    assert not grid_edge[2, 2] and not grid_edge[8, 9]  # interior
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


def fold_grid(H=8, W=12, fold_col=5.0, angle_deg=90.0):
    """A grid bent along the column line u = fold_col: flat (z = 0) before it, rising at angle_deg after it.
    Returns points (H, W, 3) and the true normals (H, W, 3) of the side each grid point lies on (the first
    side's on the fold line)."""
    r, c = np.meshgrid(np.arange(H, dtype=float), np.arange(W, dtype=float), indexing="ij")
    a = np.radians(angle_deg)
    d = np.maximum(c - fold_col, 0.0)
    pts = np.stack([np.minimum(c, fold_col) + d * np.cos(a), r, d * np.sin(a)], -1)
    n = np.where((c > fold_col)[..., None], np.array([-np.sin(a), 0.0, np.cos(a)]), np.array([0.0, 0.0, 1.0]))
    return pts, n


def slow_crease(pts, normals, faces, angle_deg):
    """Per texel, the largest angle between its normal and any face around it, faces oriented to the texel."""
    v = pts.reshape(-1, 3)
    n = normals.reshape(-1, 3)
    out = np.zeros(len(v), bool)
    for t in range(len(v)):
        for f in faces:
            if t in f:
                fn = np.cross(v[f[1]] - v[f[0]], v[f[2]] - v[f[0]])
                fn /= np.linalg.norm(fn)
                if np.dot(fn, n[f].sum(0)) < 0:
                    fn = -fn
                out[t] |= np.degrees(np.arccos(np.clip(np.dot(fn, n[t]), -1, 1))) > angle_deg
    return out


def test_texels_on_a_fold_line_are_creases_and_their_neighbours_are_not():
    """A 90-degree fold through a column of grid points: that column meets faces of both sides (90 degrees), the
    columns beside it only faces of their own side and the ones bridging nothing (the fold runs along grid
    lines). Bent half a texel off the grid points, the faces across the fold lean 45 degrees and no texel is a
    crease at 60. A gentle 30-degree bend is no crease at 60 either; None flags nothing."""
    H, W = 8, 12
    idx = np.arange(H * W)
    for fold_col, angle, expected_cols in ((5.0, 90.0, {5}), (5.5, 90.0, set()), (5.0, 30.0, set())):
        pts, n = fold_grid(H, W, fold_col, angle)
        verts, faces = grid_triangulation(pts, np.ones((H, W), bool))
        got = crease_texels(verts, faces, n.reshape(-1, 3), idx, 60.0).reshape(H, W)
        cols = {int(c) for c in np.flatnonzero(got.any(0))}
        assert cols == expected_cols, (fold_col, angle, cols)
        if expected_cols:
            assert got[:, 5].all()
        np.testing.assert_array_equal(got.ravel(), slow_crease(pts, n, faces, 60.0))
    assert not crease_texels(verts, faces, n.reshape(-1, 3), idx, None).any()


def test_crease_texels_match_a_slow_reference_on_a_bumpy_surface():
    rng = np.random.default_rng(0)
    H, W = 7, 9
    r, c = np.meshgrid(np.arange(H, dtype=float), np.arange(W, dtype=float), indexing="ij")
    pts = np.stack([c, r, rng.normal(0, 0.6, (H, W))], -1)
    verts, faces = grid_triangulation(pts, np.ones((H, W), bool))
    n = rng.normal(0, 0.3, (H, W, 3)) + np.array([0.0, 0.0, 1.0])
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    for angle in (20.0, 40.0, 70.0):
        got = crease_texels(verts, faces, n.reshape(-1, 3), np.arange(H * W), angle)
        np.testing.assert_array_equal(got, slow_crease(pts, n, faces, angle))
    with pytest.raises(GeometryError, match="'angle_deg' \\(geometry.crease_angle_deg\\)"):
        crease_texels(verts, faces, n.reshape(-1, 3), np.arange(H * W), 0.0)


def test_face_normals_turn_to_their_corners_side_whatever_the_winding():
    v = np.array([[0.0, 0, 0], [2, 0, 0], [0, 3, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 1], [3, 4, 5]])  # both windings, and a degenerate face
    up = np.tile([0.0, 0.0, 1.0], (3, 3, 1))
    n = oriented_face_normals(v, faces, up)
    assert np.allclose(n[:2], [[0, 0, 1], [0, 0, 1]]) and np.allclose(n[2], 0)
    assert np.allclose(oriented_face_normals(v, faces[:2], -up[:2]), [[0, 0, -1], [0, 0, -1]])
    # corners without a normal (zeros) do not vote; a sum perpendicular to the face keeps the winding
    one = np.zeros((2, 3, 3))
    one[:, 1] = [0.0, 0.1, -1.0]
    assert np.allclose(oriented_face_normals(v, faces[:2], one), [[0, 0, -1], [0, 0, -1]])
    side = np.zeros((2, 3, 3))
    side[:, :, 0] = 1.0
    assert np.allclose(oriented_face_normals(v, faces[:2], side), [[0, 0, 1], [0, 0, -1]])
    assert oriented_face_normals(v, np.zeros((0, 3), dtype=int), np.zeros((0, 3, 3))).shape == (0, 3)
