"""Filling texels whose parameters could not be determined (dissertation 3.2.2, Fig. 3.3).

The seed interpolates linearly inside a W x W grid window and, where the window holds no
determined texel, along the image row. Here: the median of the determined texels in the
W x W window on the surface (each channel apart; the Surface's neighbours: across an atlas's seams, round a
full-turn scan), repeated on the remaining gaps so that the window grows (MAX_PASSES times), then the median
of all determined texels. A median, not the window's mean: a measured texel next to
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

from torchrefl.core.texel_neighbours import TexelNeighbours, window_median

#: window passes: a W x W window spreads a determined value at most MAX_PASSES * (W // 2) texels
MAX_PASSES = 2
FILL_OUTSIDE, FILL_DETERMINED, FILL_WINDOW, FILL_MEDIAN = 0, 1, 2, 4


def fill_undetermined(
    neighbours: TexelNeighbours,
    values: torch.Tensor,
    known: torch.Tensor,
    inside: torch.Tensor,
    window: int = 5,
    max_passes: int = MAX_PASSES,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fill per-texel values (T, C) where `known` (T,) is False and `inside` (T,) is True.

    The window of a texel is its W x W neighbourhood on the surface (core/texel_neighbours.texel_window:
    neighbours, the Surface's, so on an atlas it reaches across chart seams and never into the gutter).
    Returns the filled values and a (T,) int8 code of how each texel was obtained:
    0 outside, 1 determined, 2 window median, 4 the median of all determined texels.
    """
    T, C = values.shape
    k = (known & inside).cpu()
    how = torch.zeros(T, dtype=torch.int8)
    how[k] = FILL_DETERMINED
    out = torch.where(k[:, None], values.cpu().to(torch.float64), torch.zeros(T, C, dtype=torch.float64))
    for _ in range(max_passes):  # undetermined values (possibly NaN) are never read
        todo = torch.nonzero(inside.cpu() & ~k)[:, 0]
        if not len(todo):
            break
        median, found = window_median(neighbours, out, k, todo, window)
        if not found.any():
            break
        can = todo[found]
        out[can] = median[found]
        k[can] = True
        how[can] = FILL_WINDOW
    todo = inside.cpu() & ~k
    if todo.any():
        ref = (known & inside).cpu()
        med = values.cpu()[ref].median(dim=0).values if ref.any() else torch.zeros(C, dtype=values.dtype)
        out[todo] = med.to(out.dtype)
        how[todo] = FILL_MEDIAN
    return out.to(values.dtype), how
