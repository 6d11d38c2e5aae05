"""Grid-neighbour lookups on the texel grid: the one helper for "the texel at (row + dy, col + dx)".

A Surface's T valid texels sit on an (H, W) grid at flat indices texel_index (row * W + col). TexelGrid maps a
texel and a grid offset to the texel there, or -1 outside the grid or the texel set; `grid_flat` is the same
lookup on a full grid (every cell present), e.g. the blocks of patches. TexelGrid is the scan's and photometric
stereo's TexelNeighbours (core/texel_neighbours.py); with wrap (a scan of the full turn) the columns close around.
"""

from __future__ import annotations

import numpy as np


def grid_flat(rows: np.ndarray, cols: np.ndarray, grid_shape: tuple[int, int]) -> np.ndarray:
    """(M,) int64 flat index row * W + col of cells (rows, cols) (M,) on an (H, W) grid, -1 outside it."""
    H, W = grid_shape
    rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
    inside = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
    return np.where(inside, np.clip(rows, 0, H - 1) * W + np.clip(cols, 0, W - 1), -1)


class TexelGrid:
    """T texels at flat indices texel_index (T,) (row * W + col, distinct) of an (H, W) grid.

    rows, cols: (T,) int64 grid row and column of each texel; slot: (H W,) int64 texel at each grid cell, -1
    where there is none; wrap: column W is column 0 again (a scan of the full turn); region: (T,) int64 zeros (one
    piece of surface: any block of the grid may form a patch)."""

    def __init__(self, texel_index, grid_shape: tuple[int, int], wrap: bool = False):
        self.grid_shape = (int(grid_shape[0]), int(grid_shape[1]))
        H, W = self.grid_shape
        self.wrap = bool(wrap)
        self.index = np.asarray(texel_index, dtype=np.int64)
        self.rows, self.cols = self.index // W, self.index % W
        self.slot = np.full(H * W, -1, dtype=np.int64)
        self.slot[self.index] = np.arange(len(self.index))
        self.region = np.zeros(len(self.index), dtype=np.int64)

    @property
    def num_texels(self) -> int:
        return int(len(self.index))

    def at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(M,) int64 texel at grid cells (rows, cols) (M,), -1 outside the grid or where there is no texel
        (columns taken modulo W with wrap)."""
        cols = np.asarray(cols, dtype=np.int64) % self.grid_shape[1] if self.wrap else cols
        cell = grid_flat(rows, cols, self.grid_shape)
        return np.where(cell >= 0, np.take(self.slot, np.maximum(cell, 0)), -1)

    def neighbour(self, texels: np.ndarray, dy: int, dx: int) -> np.ndarray:
        """(M,) int64 texel dy rows and dx columns away from each of texels (M,), -1 where there is none."""
        return self.at(np.take(self.rows, texels) + dy, np.take(self.cols, texels) + dx)

    def pairs(self, offsets=((0, 1), (1, 0))) -> np.ndarray:
        """(E, 2) int64 pairs (t, t') of texels with t' at one of the offsets from t, offset by offset, each in
        texel order (default: right and down neighbours, every adjacent pair once)."""
        return offset_pairs(self, len(self.index), offsets)


def offset_pairs(neighbours, num_texels: int, offsets) -> np.ndarray:
    """(E, 2) int64 pairs (t, neighbours.neighbour(t, dy, dx)) for each (dy, dx) of offsets in turn, texels in order,
    where the neighbour exists: the pairs of any neighbour structure with a `neighbour` method."""
    t = np.arange(num_texels)
    out = []
    for dy, dx in offsets:
        other = neighbours.neighbour(t, dy, dx)
        ok = other >= 0
        out.append(np.stack([t[ok], other[ok]], 1))
    return np.concatenate(out) if out else np.zeros((0, 2), dtype=np.int64)
