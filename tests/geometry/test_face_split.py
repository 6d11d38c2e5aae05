"""Faces split to a maximum edge length, each piece knowing where it lies on its face."""

import numpy as np
import pytest

from torchrefl.geometry.face_split import split_faces


def test_pieces_tile_their_faces_below_the_edge_length_and_their_weights_place_their_corners():
    v = np.array([[0, 0, 0], [10, 0, 0], [0, 7, 0], [0, 0, 1.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    corners, parent, bary = split_faces(v, f, 2.0)
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    assert edges.max() <= 2.0 + 1e-9
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    assert np.bincount(parent, weights=area) == pytest.approx([35.0, 3.5])
    assert np.allclose(np.einsum("ejk,eki->eji", bary, v[f[parent]]), corners)
    assert (bary >= -1e-12).all() and np.allclose(bary.sum(2), 1)
    small = split_faces(v, f, 100.0)  # faces already small enough stay whole
    assert np.array_equal(small[1], [0, 1]) and np.allclose(small[0], v[f])
