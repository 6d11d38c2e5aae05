"""The Surface's one neighbour structure (core/texel_neighbours.py): windows walked on the surface, their medians,
the grid's column wrap on a full turn, and the structure each Surface carries."""

import numpy as np
import pytest
import torch
from conftest import atlas_cube

from torchrefl.core.surface import Surface
from torchrefl.core.texel_grid import TexelGrid
from torchrefl.core.texel_neighbours import TexelNeighbours, texel_window, window_median, window_offsets
from torchrefl.errors import GeometryError


def flat_surface(index, grid_shape, **options) -> Surface:
    T = len(index)
    up = torch.zeros(T, 3, dtype=torch.float64)
    up[:, 2] = 1.0
    return Surface(
        grid_shape, torch.as_tensor(index), torch.zeros(T, 3).double(), up, torch.ones(T).double(), **options
    )


def test_a_window_on_a_grid_is_the_cells_around_the_texel():
    H, W = 5, 6
    index = np.array([0, 1, 2, 7, 8, 14, 29])  # a ragged texel set
    cell = {int(g): k for k, g in enumerate(index)}
    win = texel_window(TexelGrid(index, (H, W)), 1)
    assert win.shape == (len(index), 9)
    for t, g in enumerate(index):
        r, c = divmod(int(g), W)
        want = [
            cell.get((r + dy) * W + c + dx, -1) if 0 <= r + dy < H and 0 <= c + dx < W else -1
            for dy, dx in window_offsets(1)
        ]
        assert win[t].tolist() == want


def test_columns_wrap_on_a_full_turn_only():
    H, W = 3, 5
    index = np.arange(H * W)
    wrapped, plain = TexelGrid(index, (H, W), wrap=True), TexelGrid(index, (H, W))
    last = np.array([1 * W + W - 1])  # row 1, last column
    assert wrapped.neighbour(last, 0, 1).tolist() == [1 * W]  # row 1, column 0
    assert plain.neighbour(last, 0, 1).tolist() == [-1]
    assert wrapped.neighbour(np.array([0]), 0, -2).tolist() == [W - 2]
    assert wrapped.neighbour(np.array([0]), -1, 0).tolist() == [-1]  # rows do not wrap
    assert {(1 * W + W - 1, 1 * W)} <= {tuple(p) for p in wrapped.pairs().tolist()}
    assert (1 * W + W - 1, 1 * W) not in {tuple(p) for p in plain.pairs().tolist()}


def test_the_window_median_counts_known_texels_only():
    H, W = 4, 4
    g = TexelGrid(np.arange(H * W), (H, W))
    values = torch.arange(H * W, dtype=torch.float64)[:, None]
    known = torch.zeros(H * W, dtype=torch.bool)
    known[[0, 1, 4, 15]] = True
    med, found = window_median(g, values, known, torch.tensor([5, 10, 3]), 3)
    # texel 5 (1, 1): known 0, 1, 4 in its window -> 1; texel 10 (2, 2): 15 -> 15; texel 3 (0, 3): none
    assert med[:2, 0].tolist() == [1.0, 15.0] and torch.isnan(med[2, 0])
    assert found.tolist() == [True, True, False]


def test_every_surface_carries_one_neighbour_structure():
    s = flat_surface(np.array([0, 1, 5]), (2, 3))
    assert isinstance(s.neighbours, TexelGrid) and isinstance(s.neighbours, TexelNeighbours)
    assert not s.neighbours.wrap and s.neighbours.index.tolist() == [0, 1, 5]
    given = TexelGrid(np.array([0, 1, 5]), (2, 3), wrap=True)
    s = flat_surface(np.array([0, 1, 5]), (2, 3), neighbours=given)
    assert s.neighbours is given and s.to(torch.float32).neighbours is given
    cube = atlas_cube().surface
    assert isinstance(cube.neighbours, TexelNeighbours) and cube.to(torch.float32).neighbours is cube.neighbours
    with pytest.raises(GeometryError, match="'neighbours' covers 2 texels"):
        flat_surface(np.array([0, 1, 5]), (2, 3), neighbours=TexelGrid(np.array([0, 1]), (2, 3)))
