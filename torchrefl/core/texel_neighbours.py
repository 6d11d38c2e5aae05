"""Texel neighbours on the surface: the one structure behind every "texel next to this one".

Each capture kind hands its Surface a TexelNeighbours (Surface.neighbours): the scan its grid (core/texel_grid.py
TexelGrid, columns closing around on a full turn), photometric stereo the plain image grid, a mesh's atlas
geometry/atlas_neighbours.AtlasNeighbours (within charts and across chart seams; the gutter is no surface). The
stages ask it, never the grid: smoothing pairs (`pairs`), windows of radius r walked step by step
(`texel_window`, `window_median`), density kernels (`neighbour` per offset) and patch blocks (`region`: a block
never joins texels of two regions).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
import torch


@runtime_checkable
class TexelNeighbours(Protocol):
    """What every stage may ask of a Surface's neighbour structure.

    grid_shape (H, W) of the parameter maps; rows, cols (T,) int64 grid cell of each texel; region (T,) int64
    piece of surface each texel lies on (0 on a grid; the chart on an atlas); num_texels T."""

    grid_shape: tuple[int, int]
    rows: np.ndarray
    cols: np.ndarray
    region: np.ndarray

    @property
    def num_texels(self) -> int: ...

    def at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(M,) int64 texel in grid cells (rows, cols) (M,), -1 where there is none."""

    def neighbour(self, texels: np.ndarray, dy: int, dx: int) -> np.ndarray:
        """(M,) int64 texel dy rows and dx columns away from each of texels (M,) on the surface, -1 where none."""

    def pairs(self, offsets=((0, 1), (1, 0))) -> np.ndarray:
        """(E, 2) int64 pairs of neighbouring texels (default: every adjacent pair once)."""


def window_offsets(radius: int) -> list[tuple[int, int]]:
    """The (2 radius + 1)^2 offsets (dy, dx) of a square window, dy outer, dx inner (row-major)."""
    return [(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)]


def texel_window(neighbours: TexelNeighbours, radius: int, texels=None) -> np.ndarray:
    """(M, K) int64 texels at each of window_offsets(radius) (K of them) from texels (M,) (default: all), each
    reached by neighbours.neighbour (on an atlas a walk across seams); -1 where there is none."""
    t = np.arange(neighbours.num_texels) if texels is None else np.asarray(texels, dtype=np.int64)
    cols = [neighbours.neighbour(t, dy, dx) for dy, dx in window_offsets(radius)]
    return np.stack(cols, 1) if cols else np.zeros((len(t), 0), dtype=np.int64)


def window_median(
    neighbours: TexelNeighbours, values: torch.Tensor, known: torch.Tensor, texels: torch.Tensor, window: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The median, channel by channel, of values (T, C) over the known (T,) bool texels in the W x W window (W =
    window, odd; texel_window) of each of texels (M,) int64: (median (M, C), NaN where the window holds no known
    texel; found (M,) bool, the window holds one)."""
    win = torch.from_numpy(texel_window(neighbours, window // 2, texels.cpu().numpy()))  # (M, K)
    ok = (win >= 0) & known.cpu()[win.clamp_min(0)]
    gathered = values.cpu()[win.clamp_min(0)]  # (M, K, C)
    gathered = torch.where(ok[..., None], gathered, torch.full_like(gathered, float("nan")))
    return gathered.nanmedian(1).values.to(values.device), ok.any(1).to(values.device)
