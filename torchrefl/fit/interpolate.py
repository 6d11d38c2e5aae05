"""Filling texels whose parameters could not be determined (dissertation 3.2.2, Fig. 3.3).

The seed interpolates linearly inside a W x W window and, where the window holds no
determined texel, along the image row. Here: the mean of the determined texels in the
W x W window (a masked box filter, kornia.filters.box_blur), repeated on the remaining
gaps so that the window effectively grows, then linear interpolation along rows, then
the median of all determined texels as the last resort.
"""

from __future__ import annotations

import numpy as np
import torch
from kornia.filters import box_blur


def fill_undetermined(
    grid: torch.Tensor, known: torch.Tensor, inside: torch.Tensor, window: int = 5, max_passes: int = 8
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fill grid values (H, W, C) where `known` (H, W) is False and `inside` (H, W) is True.

    Returns the filled grid and a (H, W) int8 map of how each texel was obtained:
    0 outside, 1 determined, 2 window mean, 3 row interpolation, 4 global median.
    """
    H, W, C = grid.shape
    g = grid.permute(2, 0, 1)[None].to(torch.float64)  # (1, C, H, W)
    k = (known & inside).to(torch.float64)[None, None]
    how = torch.zeros(H, W, dtype=torch.int8)
    how[known & inside] = 1
    values = g * k
    for _ in range(max_passes):
        todo = inside & (k[0, 0] == 0)
        if not todo.any():
            break
        num = box_blur(values, (window, window), border_type="constant", separable=True)
        den = box_blur(k, (window, window), border_type="constant", separable=True)
        can = todo & (den[0, 0] > 1e-9)
        if not can.any():
            break
        mean = num / den.clamp_min(1e-12)
        values = torch.where(can[None, None], mean, values)
        k = torch.where(can[None, None], torch.ones_like(k), k)
        how[can] = 2
    out = values[0].permute(1, 2, 0).clone()
    todo = inside & (k[0, 0] == 0)
    if todo.any():
        filled = k[0, 0] > 0
        arr = out.numpy()
        for r in np.flatnonzero(todo.any(dim=1).numpy()):
            xs = np.flatnonzero(filled[r].numpy())
            if xs.size == 0:
                continue
            miss = np.flatnonzero(todo[r].numpy())
            for c in range(C):
                arr[r, miss, c] = np.interp(miss, xs, arr[r, xs, c])
            how[r, miss] = 3
        out = torch.from_numpy(arr)
        todo = inside & (how == 0)
        if todo.any():
            ref = known & inside
            med = grid[ref].median(dim=0).values if ref.any() else torch.zeros(C, dtype=grid.dtype)
            out[todo] = med.to(out.dtype)
            how[todo] = 4
    return out.to(grid.dtype), how
