"""torchrefl.report.hit_texels: a hit's texel coordinates on the scan grid (across the seam) and on an atlas, the
texels it reads (bilinear over estimated texels only, or nearest; on an atlas only texels of the hit's own chart)
and the estimate sampled there."""

import numpy as np
from conftest import atlas_room

from torchrefl.geometry.atlas import rasterise_atlas
from torchrefl.geometry.mesh_file import MeshData
from torchrefl.report.hit_texels import (
    atlas_texel_mesh,
    bilinear_weights,
    grid_texel_mesh,
    nearest_weights,
    sample_texels,
    texel_image,
)
from torchrefl.synthetic.uv_objects import ellipsoid


def _cylinder(H=4, W=8, r=10.0):
    a = 2 * np.pi * np.arange(W) / W
    rows = np.arange(H, dtype=float)
    pos = np.stack([np.broadcast_to(-r * np.sin(a), (H, W)), -np.broadcast_to(rows[:, None], (H, W)),
                    np.broadcast_to(-r * np.cos(a), (H, W))], -1)  # fmt: skip
    return pos, pos * np.array([1.0, 0.0, 1.0]) / r


def test_grid_hits_map_to_their_texels_and_across_the_seam():
    pos, n = _cylinder()
    mesh = grid_texel_mesh(pos, n)
    assert mesh.wrap and len(mesh.faces) == 2 * 3 * 8  # 3 rows of quads, 8 columns with the seam
    bary = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    for f in range(len(mesh.faces)):  # a face's corners are its grid points (vertex k = grid point k)
        coords = mesh.texel_coords(np.full(3, f), bary)
        rows, cols = mesh.faces[f] // 8, mesh.faces[f] % 8
        np.testing.assert_allclose(coords[:, 0], rows)
        np.testing.assert_allclose(np.mod(coords[:, 1], 8), cols)
        assert np.ptp(coords[:, 1]) <= 1.0  # unwrapped: one column apart, also across the seam
    seam = [f for f in range(len(mesh.faces)) if {0, 7} <= set(mesh.faces[f] % 8)]
    mid = mesh.texel_coords(np.array(seam[:1]), np.array([[1 / 3, 1 / 3]]))
    assert 7.0 < mid[0, 1] < 8.0


def test_atlas_corners_map_to_texel_centres():
    uvs = np.array([[[0.5 / 4, 1 - 0.5 / 4], [3.5 / 4, 1 - 0.5 / 4], [0.5 / 4, 1 - 2.5 / 4]]])
    mesh = atlas_texel_mesh(MeshData(np.eye(3), np.array([[0, 1, 2]]), uvs, source="tri"), (4, 4))
    coords = mesh.texel_coords(np.zeros(3, int), np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
    np.testing.assert_allclose(coords, [[0, 0], [0, 3], [2, 0]], atol=1e-12)  # (row, col) of texels (0,0) (0,3) (2,0)


def _estimate(pd, mask):
    """A TexelImage of pd (H, W, 3) (ps = pd's first channel, sigma = pd's first channel) on mask (H, W)."""
    return texel_image(pd, pd[..., :1], pd[..., 0], mask)


def test_bilinear_uses_estimated_texels_only_and_nearest_picks_one():
    H, W = 2, 3
    pd = np.zeros((H, W, 3))
    pd[0, 0], pd[0, 1], pd[1, 0] = 0.2, 0.6, 0.9
    mask = np.zeros((H, W), bool)
    mask[0, 0] = mask[0, 1] = True
    texels = _estimate(pd, mask)
    coords = np.array([[0.0, 0.5], [0.5, 0.0], [1.0, 2.0], [0.0, 0.8]])
    s = sample_texels(texels, bilinear_weights(coords, (H, W)))
    np.testing.assert_allclose(s.pd[:, 0], [0.4, 0.2, 0.0, 0.2 * 0.2 + 0.6 * 0.8], rtol=1e-6)  # [1, 0] not estimated
    assert s.estimated.tolist() == [True, True, False, True]
    near = sample_texels(texels, nearest_weights(np.array([[0.0, 0.8], [0.4, 0.3]]), (H, W)))
    np.testing.assert_allclose(near.pd[:, 0], [0.6, 0.2], rtol=1e-6)
    wrapped = sample_texels(
        _estimate(pd, np.ones((H, W), bool)), bilinear_weights(np.array([[0.0, 2.5]]), (H, W), True)
    )
    np.testing.assert_allclose(wrapped.pd[0, 0], (0.0 + 0.2) / 2, rtol=1e-6)  # column 3 is column 0
    off = sample_texels(texels, bilinear_weights(np.array([[-0.5, -0.5], [-2.0, 0.0]]), (H, W)))
    np.testing.assert_allclose(off.pd[:, 0], [0.2, 0.0], rtol=1e-6)  # off the grid weighs 0
    assert off.estimated.tolist() == [True, False]


def test_atlas_hits_read_texels_of_their_own_chart_only():
    """The cube room's charts touch or lie a texel apart in UV, shifted off the grid (border cells partly gutter or
    another chart's): every hit reads texels of its face's chart (chart k = cube face k = mesh faces 2k, 2k + 1, by
    construction), a texel's value is its chart's, so each hit reads exactly its chart's value, bilinear or nearest."""
    S = 32
    for gap in (0, 1):
        mesh = atlas_room(texture_size=S, gap=gap).mesh
        tm = atlas_texel_mesh(mesh, (S, S))
        atlas = rasterise_atlas(mesh, S)
        chart = np.full(S * S, -1)
        chart[atlas.texel_index] = atlas.face // 2
        pd = np.where(chart >= 0, 0.1 + 0.1 * chart, 0.0).reshape(S, S, 1).repeat(3, -1)
        texels = _estimate(pd, chart.reshape(S, S) >= 0)
        rng = np.random.default_rng(gap)
        tri = rng.integers(0, len(mesh.faces), 3000)
        bary = rng.dirichlet([1.0, 1.0, 1.0], 3000)[:, 1:]
        for interpolation in ("bilinear", "nearest"):
            w = tm.texel_weights(tri, bary, interpolation)
            assert (chart[w.index][w.weight > 0] == np.repeat(tri // 2, w.index.shape[1])[w.weight.ravel() > 0]).all()
            s = sample_texels(texels, w)
            assert s.estimated.all()
            np.testing.assert_allclose(s.pd[:, 0], 0.1 + 0.1 * (tri // 2), rtol=1e-6)


def test_a_uv_sphere_pole_without_texel_centres_reads_the_next_row():
    """An ellipsoid with twice as many segments as atlas columns: no texel centre lies in the thin pole triangles of
    atlas row 0, so hits there read row 1 of the chart (nearest cell of the chart), not nothing (a hole at the pole)."""
    obj = ellipsoid(rings=16, segments=32)
    mesh = MeshData(obj.mesh.vertices, obj.mesh.faces, obj.uv[obj.mesh.faces], source="ellipsoid")
    S = 16
    tm = atlas_texel_mesh(mesh, (S, S))
    row = np.full(S * S, -1)
    row[tm.atlas.texel_index] = tm.atlas.texel_index // S
    assert (tm.atlas.texel_index // S).min() == 1  # row 0 holds no texel
    pole = np.flatnonzero(np.isclose(obj.uv[obj.mesh.faces][..., 1].max(1), 1.0))  # the top fan's faces
    assert len(pole) == 32
    bary = np.tile([[0.1, 0.1], [0.3, 0.3], [0.05, 0.9]], (len(pole), 1))  # near the pole, mid-face, near the ring
    tri = np.repeat(pole, 3)
    mask = np.zeros(S * S, bool)
    mask[tm.atlas.texel_index] = True
    for interpolation in ("bilinear", "nearest"):
        w = tm.texel_weights(tri, bary, interpolation)
        assert (row[w.index][w.weight > 0] == 1).all()
        assert sample_texels(_estimate(np.ones((S, S, 3)), mask.reshape(S, S)), w).estimated.all()
