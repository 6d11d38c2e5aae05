"""capture.shadow_edges: the lit observations whose footprint a cast shadow's edge may cross."""

import numpy as np
from conftest import fold_surface

from torchrefl.capture.shadow_edges import face_neighbours, shadow_edge_observations, with_adjacent
from torchrefl.core.texel_grid import TexelGrid


def edges(shadowed, neighbours, normals):
    return shadow_edge_observations(shadowed, face_neighbours(neighbours, normals))


def test_lit_texels_next_to_a_cast_shadow_on_their_face_are_flagged():
    """Light 0 casts a shadow over the floor's first 5 columns: the lit column next to it (5) is flagged in every
    row, the columns further on and the shadowed texels are not. Light 1 shadows the whole wall: the floor's column
    next to the fold is not flagged (its shadowed neighbour lies across the fold, which is no edge inside its
    footprint), and neither is anything else."""
    s = fold_surface(8, 24)  # columns 0-11 the floor, 12-23 the wall
    col = s.texel_index.numpy() % 24
    shadowed = np.stack([col < 5, col >= 12])
    edge = edges(shadowed, s.neighbours, s.normals.numpy())
    assert edge.shape == shadowed.shape
    assert np.array_equal(edge[0], col == 5)
    assert not edge[1].any()
    assert not (edge & shadowed).any()


def test_every_direction_counts_and_holes_and_the_seam_are_handled():
    """One shadowed texel in the middle of the floor flags exactly its four grid neighbours (above, below, left,
    right; not the diagonals); a texel missing from the set next to it is no neighbour; on a scan of the full turn
    (wrap) a shadow in the last column flags the first, and without wrap it does not."""
    s = fold_surface(9, 24)
    index = s.texel_index.numpy()
    row, col = index // 24, index % 24
    centre = (row == 4) & (col == 5)
    edge = edges(centre[None], s.neighbours, s.normals.numpy())[0]
    four = ((row == 3) | (row == 5)) & (col == 5) | (row == 4) & ((col == 4) | (col == 6))
    assert np.array_equal(edge, four)
    keep = ~((row == 4) & (col == 6))  # a hole right of the shadowed texel
    edge = edges(centre[keep][None], TexelGrid(index[keep], s.grid_shape), s.normals.numpy()[keep])[0]
    assert np.array_equal(edge, four[keep])
    wall = col >= 12  # the wall alone as a 9 x 12 grid: its last column is next to its first when the scan wraps
    wall_index = row[wall] * 12 + (col[wall] - 12)
    seam = (wall_index % 12 == 11) & (wall_index // 12 == 2)
    n = s.normals.numpy()[wall]
    wrapped = edges(seam[None], TexelGrid(wall_index, (9, 12), wrap=True), n)[0]
    plain = edges(seam[None], TexelGrid(wall_index, (9, 12)), n)[0]
    first = (wall_index % 12 == 0) & (wall_index // 12 == 2)
    assert wrapped[first].all() and not plain[first].any()


def test_on_an_atlas_the_neighbour_across_the_seam_counts():
    """The open cylinder's one chart meets itself along a UV seam: a shadowed texel in the chart's first column
    flags its left neighbour, which is in the last column of the atlas (the plain grid of the same texels finds no
    texel there)."""
    from conftest import atlas_cylinder

    s = atlas_cylinder().surface
    nb = s.neighbours
    first = (nb.cols == nb.cols.min()) & (nb.rows == 10)
    last = (nb.cols == nb.cols.max()) & (nb.rows == 10)
    edge = edges(first[None], nb, s.normals.numpy())[0]
    assert edge[last].all() and edge.sum() == 4
    plain = edges(first[None], TexelGrid(s.texel_index.numpy(), s.grid_shape), s.normals.numpy())[0]
    assert not plain[last].any() and plain.sum() == 3


def test_with_adjacent_adds_the_face_neighbours_and_keeps_the_texels():
    s = fold_surface(6, 24)  # columns 0-11 the floor, 12-23 the wall
    index = s.texel_index.numpy()
    texels = np.zeros(len(index), bool)
    texels[index == 2 * 24 + 11] = True  # the floor's last column, beside the fold: its wall neighbour is no face's
    out = with_adjacent(texels, face_neighbours(s.neighbours, s.normals.numpy()))
    assert sorted(index[out].tolist()) == [1 * 24 + 11, 2 * 24 + 10, 2 * 24 + 11, 3 * 24 + 11]
