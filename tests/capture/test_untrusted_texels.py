"""untrusted_texels.shadow_edge_observations: the lit observations whose footprint a cast shadow's edge may cross."""

import numpy as np
from conftest import fold_surface

from torchrefl.capture.untrusted_texels import shadow_edge_observations


def test_lit_texels_next_to_a_cast_shadow_on_their_face_are_flagged():
    """Light 0 casts a shadow over the floor's first 5 columns: the lit column next to it (5) is flagged in every
    row, the columns further on and the shadowed texels are not. Light 1 shadows the whole wall: the floor's column
    next to the fold is not flagged (its shadowed neighbour lies across the fold, which is no edge inside its
    footprint), and neither is anything else."""
    s = fold_surface(8, 24)  # columns 0-11 the floor, 12-23 the wall
    col = s.texel_index.numpy() % 24
    shadowed = np.stack([col < 5, col >= 12])
    edge = shadow_edge_observations(shadowed, s.texel_index.numpy(), s.grid_shape, s.normals.numpy())
    assert edge.shape == shadowed.shape
    assert np.array_equal(edge[0], col == 5)
    assert not edge[1].any()
    assert not (edge & shadowed).any()
