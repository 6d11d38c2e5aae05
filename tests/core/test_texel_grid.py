"""TexelGrid and grid_flat against per-texel loops over a dict of grid cells."""

import numpy as np
import pytest

from torchrefl.core.texel_grid import TexelGrid, grid_flat


@pytest.fixture
def grid():
    rng = np.random.default_rng(0)
    H, W = 7, 9
    index = np.sort(rng.choice(H * W, 40, replace=False))
    return H, W, index


def reference_neighbour(H, W, index, t, dy, dx):
    cell = {int(g): k for k, g in enumerate(index)}
    r, c = divmod(int(index[t]), W)
    rr, cc = r + dy, c + dx
    if not (0 <= rr < H and 0 <= cc < W):
        return -1
    return cell.get(rr * W + cc, -1)


def test_neighbour_and_at_match_the_loop(grid):
    H, W, index = grid
    g = TexelGrid(index, (H, W))
    t = np.arange(len(index))
    for dy in range(-3, 4):
        for dx in range(-3, 4):
            got = g.neighbour(t, dy, dx)
            assert got.dtype == np.int64
            assert got.tolist() == [reference_neighbour(H, W, index, k, dy, dx) for k in t]
    sub = np.array([5, 0, 5, 39])  # any subset, repeats allowed
    assert g.neighbour(sub, 0, 1).tolist() == [reference_neighbour(H, W, index, k, 0, 1) for k in sub]
    assert g.at(g.rows, g.cols).tolist() == t.tolist()
    assert g.at(np.array([-1, H, 0]), np.array([0, 0, W])).tolist() == [-1, -1, -1]


def test_pairs_are_every_adjacent_pair_once(grid):
    H, W, index = grid
    pairs = TexelGrid(index, (H, W)).pairs()
    ref = [(k, reference_neighbour(H, W, index, k, dy, dx)) for dy, dx in ((0, 1), (1, 0)) for k in range(len(index))]
    assert pairs.tolist() == [[a, b] for a, b in ref if b >= 0]
    assert TexelGrid(index, (H, W)).pairs(()).shape == (0, 2)


def test_grid_flat_matches_the_loop():
    rows = np.array([-1, 0, 2, 3, 2, 0])
    cols = np.array([0, 0, 4, 1, 5, -2])
    ref = [r * 5 + c if 0 <= r < 3 and 0 <= c < 5 else -1 for r, c in zip(rows, cols)]
    assert grid_flat(rows, cols, (3, 5)).tolist() == ref
