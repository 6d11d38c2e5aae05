"""Texels beside a cast shadow (torchrefl.capture.shadow_edges) on a grid whose neighbours are counted by hand."""

import numpy as np

from torchrefl.capture.shadow_edges import adjacent_texels, shadow_edge, with_adjacent
from torchrefl.core.texel_grid import TexelGrid


def grid(H: int, W: int, wrap: bool = False) -> TexelGrid:
    return TexelGrid(np.arange(H * W), (H, W), wrap=wrap)


def test_the_lit_texels_one_step_from_a_shadow_are_its_edge():
    H, W = 5, 6
    shadowed = np.zeros(H * W, bool)
    shadowed[2 * W + 2] = True  # one shadowed texel at row 2, column 2
    lit = np.ones(H * W, bool)
    lit[0] = False  # not lit: never an edge texel, whatever its neighbours
    edge = shadow_edge(lit, shadowed, adjacent_texels(grid(H, W)))
    assert sorted(np.flatnonzero(edge).tolist()) == [1 * W + 2, 2 * W + 1, 2 * W + 3, 3 * W + 2]


def test_a_shadow_across_the_wrap_of_a_full_turn_marks_the_far_column():
    H, W = 3, 4
    shadowed = np.zeros(H * W, bool)
    shadowed[1 * W + 0] = True
    edge = shadow_edge(np.ones(H * W, bool), shadowed, adjacent_texels(grid(H, W, wrap=True)))
    assert edge[1 * W + W - 1] and edge[1 * W + 1] and edge[0] and edge[2 * W]
    assert edge.sum() == 4


def test_with_adjacent_adds_the_four_neighbours_and_keeps_the_texels():
    H, W = 4, 4
    texels = np.zeros(H * W, bool)
    texels[0] = True  # a corner: two neighbours
    out = with_adjacent(texels, adjacent_texels(grid(H, W)))
    assert sorted(np.flatnonzero(out).tolist()) == [0, 1, W]
