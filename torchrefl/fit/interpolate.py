"""Filling texels whose parameters could not be determined (dissertation 3.2.2, Fig. 3.3).

The seed interpolates linearly inside a W x W window and, where the window holds no
determined texel, along the image row. Here: the median of the determined texels in the
W x W window (each channel apart), repeated on the remaining gaps so that the window grows (MAX_PASSES
times), then the median of all determined texels. A median, not the window's mean: a measured texel next to
a silhouette with few highlights can carry an extreme lobe (Ps at its bound, sigma narrow), and a mean
spread it over its unmeasured neighbours, whose Pd then took the rest of their highlights (Pd-bound texels of
the default scene: rms 0.030 with the mean, 0.005 with the median; docs/results/default.md).
Not the seed's row interpolation: on the non-uniform glossy fold a scan row of the lower plate
(no highlight from any light) then carried the lobe of the one stray texel it held across the
whole plate (Ps 0.04 against 0.26-0.44), and its Pd came out 8 % high; with the object's median lobe
3 % (docs/results/fold.md). A lobe measured further away than a few windows is no better evidence
than the object's typical one.
"""

from __future__ import annotations

import torch
from kornia.filters import box_blur

#: window passes: a W x W mean spreads a determined value at most MAX_PASSES * (W // 2) texels
MAX_PASSES = 2
FILL_OUTSIDE, FILL_DETERMINED, FILL_WINDOW, FILL_MEDIAN = 0, 1, 2, 4


def fill_undetermined(
    grid: torch.Tensor, known: torch.Tensor, inside: torch.Tensor, window: int = 5, max_passes: int = MAX_PASSES
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fill grid values (H, W, C) where `known` (H, W) is False and `inside` (H, W) is True.

    Returns the filled grid and a (H, W) int8 map of how each texel was obtained:
    0 outside, 1 determined, 2 window median, 4 the median of all determined texels.
    """
    H, W, C = grid.shape
    g = grid.permute(2, 0, 1)[None].to(torch.float64)  # (1, C, H, W)
    k = (known & inside).to(torch.float64)[None, None]
    how = torch.zeros(H, W, dtype=torch.int8)
    how[known & inside] = 1
    values = torch.where(k > 0, g, torch.zeros_like(g))  # undetermined values (possibly NaN) are never read
    for _ in range(max_passes):
        todo = inside & (k[0, 0] == 0)
        if not todo.any():
            break
        den = box_blur(k, (window, window), border_type="constant", separable=True)
        can = todo & (den[0, 0] > 1e-9)
        if not can.any():
            break
        values = window_median(values, k, can, window)
        k = torch.where(can[None, None], torch.ones_like(k), k)
        how[can] = 2
    out = values[0].permute(1, 2, 0).clone()
    todo = inside & (k[0, 0] == 0)
    if todo.any():
        ref = known & inside
        med = grid[ref].median(dim=0).values if ref.any() else torch.zeros(C, dtype=grid.dtype)
        out[todo] = med.to(out.dtype)
        how[todo] = FILL_MEDIAN
    return out.to(grid.dtype), how


def window_median(values: torch.Tensor, k: torch.Tensor, can: torch.Tensor, window: int) -> torch.Tensor:
    """values (1, C, H, W) with the texels in can (H, W) set to the median of the determined (k > 0) values in their
    W x W window (each channel apart); only those texels' windows are gathered."""
    r = window // 2
    known = torch.where(k > 0, values, torch.full_like(values, float("nan")))
    padded = torch.nn.functional.pad(known, (r, r, r, r), value=float("nan"))[0]
    windows = padded.unfold(1, window, 1).unfold(2, window, 1)  # (C, H, W, window, window), a view
    rows, cols = can.nonzero(as_tuple=True)
    median = windows[:, rows, cols].reshape(values.shape[1], -1, window * window).nanmedian(-1).values
    out = values.clone()
    out[0, :, rows, cols] = median
    return out
