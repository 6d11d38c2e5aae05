"""The distinct rows of a table, in the order of their first occurrence (images that share a light or a direct
irradiance: transport.photon_refresh.distinct_lights, transport.radiosity_level.distinct_emitters)."""

from __future__ import annotations

import numpy as np


def distinct_rows(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """first (U,) the index of the first row of each distinct row of key (N, ...) (equal bit for bit), in order of
    first occurrence; of (N,) each row's distinct row, 0..U-1."""
    key = np.asarray(key)
    if not len(key):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    _, first, of = np.unique(key.reshape(len(key), -1), axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return first[order], rank[np.asarray(of).reshape(-1)]
