"""core.distinct_rows: the distinct rows of a table in the order of their first occurrence."""

import numpy as np

from torchrefl.core.distinct_rows import distinct_rows


def test_distinct_rows_follow_their_first_occurrence_not_their_sort_order():
    a, b, c = [3.0, 1.0], [2.0, 0.0], [1.0, 5.0]  # np.unique sorts them c, b, a
    first, of = distinct_rows(np.array([a, b, a, c, b, c]))
    assert first.tolist() == [0, 1, 3] and of.tolist() == [0, 1, 0, 2, 1, 2]
    first, of = distinct_rows(np.array([[[1.0], [2.0]], [[1.0], [2.0 + 1e-12]]]))  # (N, ...) rows, compared exactly
    assert first.tolist() == [0, 1] and of.tolist() == [0, 1]
    first, of = distinct_rows(np.zeros((0, 4)))
    assert first.size == 0 and of.size == 0
