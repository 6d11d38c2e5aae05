"""torchrefl.report.hit_texels: a hit's texel coordinates on the scan grid (across the seam) and on an atlas, and
the estimate sampled there (bilinear over estimated texels only, or nearest)."""

import numpy as np

from torchrefl.report.hit_texels import atlas_texel_mesh, grid_texel_mesh, sample_texels, texel_image


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
    mesh = atlas_texel_mesh(np.eye(3), np.array([[0, 1, 2]]), uvs, (4, 4))
    coords = mesh.texel_coords(np.zeros(3, int), np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
    np.testing.assert_allclose(coords, [[0, 0], [0, 3], [2, 0]], atol=1e-12)  # (row, col) of texels (0,0) (0,3) (2,0)


def test_bilinear_uses_estimated_texels_only_and_nearest_picks_one():
    H, W = 2, 3
    pd = np.zeros((H, W, 3))
    pd[0, 0], pd[0, 1], pd[1, 0] = 0.2, 0.6, 0.9
    mask = np.zeros((H, W), bool)
    mask[0, 0] = mask[0, 1] = True
    n = np.broadcast_to([0.0, 0.0, 1.0], (H, W, 3))
    texels = texel_image(pd, pd[..., :1], pd[..., 0], n, mask)
    s = sample_texels(texels, np.array([[0.0, 0.5], [0.5, 0.0], [1.0, 2.0], [0.0, 0.8]]))
    np.testing.assert_allclose(s.pd[:, 0], [0.4, 0.2, 0.0, 0.2 * 0.2 + 0.6 * 0.8], rtol=1e-6)  # [1, 0] not estimated
    assert s.estimated.tolist() == [True, True, False, True]
    np.testing.assert_allclose(s.normals[:2], [[0, 0, 1], [0, 0, 1]], atol=1e-6)
    near = sample_texels(texels, np.array([[0.0, 0.8], [0.4, 0.3]]), "nearest")
    np.testing.assert_allclose(near.pd[:, 0], [0.6, 0.2], rtol=1e-6)
    wrapped = sample_texels(texel_image(pd, pd[..., :1], pd[..., 0], n, np.ones((H, W), bool), wrap=True),
                            np.array([[0.0, 2.5]]))  # fmt: skip
    np.testing.assert_allclose(wrapped.pd[0, 0], (0.0 + 0.2) / 2, rtol=1e-6)  # column 3 is column 0
