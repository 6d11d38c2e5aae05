"""PhotonHits (torchrefl.transport.photon_hits): a subset of the hits keeps each hit's fields together and the
totals of all."""

import numpy as np

from torchrefl.transport.photon_hits import PhotonHits


def test_taking_hits_keeps_their_fields_together_and_the_totals_of_all():
    hits = PhotonHits(
        source=np.array([0, 1, 1, 2]),
        texel=np.array([5, 6, 7, 8]),
        direction=np.arange(12, dtype=np.float32).reshape(4, 3),
        power=np.arange(12, 24, dtype=np.float32).reshape(4, 3),
        emitted=np.array([10, 20, 30]),
        rays=99,
        emitter=np.array([1, 2, 3, 4]),
        back_hits=3,
        specular_path=np.array([True, False, True, False]),
    )
    sub = hits.take(np.array([3, 1]))
    assert sub.count == 2 and hits.count == 4
    np.testing.assert_array_equal(sub.source, [2, 1])
    np.testing.assert_array_equal(sub.texel, [8, 6])
    np.testing.assert_array_equal(sub.direction, [[9, 10, 11], [3, 4, 5]])
    np.testing.assert_array_equal(sub.power, [[21, 22, 23], [15, 16, 17]])
    np.testing.assert_array_equal(sub.emitter, [4, 2])
    np.testing.assert_array_equal(sub.specular_path, [False, False])
    assert sub.diffuse_per_pd is None and sub.density_weight is None  # absent fields stay absent
    np.testing.assert_array_equal(sub.emitted, [10, 20, 30])
    assert (sub.rays, sub.back_hits) == (99, 3)
