"""Texels the fitted model cannot explain: their image residual stands far out of the object's.

The range data miss some mixed footprints (a texel one row inside a plate's 3 mm rim, whose sub-pixels see
the rim face in some images): one normal cannot explain their observations, the fit pushes their Pd where
the residual is least bad, and on the non-uniform glossy fold 292 of the 325 measured texels off by more
than 10 % in Pd were such texels. After the fit, a texel whose RMS residual over its fitted observations
exceeds the median texel's by MISFIT_DEVIATIONS robust deviations, within NEAR_EDGE texels of the scanned
surface's edge or of untrusted geometry (where mixed footprints are), is reported as a misfit (coverage code 6)
and, like untrusted geometry, has no estimate and is left out of the metrics. Interior texels are never
dropped: a misfit there is the model's, and the metrics must show it.
"""

from __future__ import annotations

import torch

from torchrefl.core.robust import robust_std
from torchrefl.core.texel_neighbours import TexelNeighbours, texel_window

#: robust deviations (1.4826 x the median absolute deviation) above the median texel RMS residual
MISFIT_DEVIATIONS = 8.0
#: the deviation is at least this many 8-bit DN (a noise-free synthetic fit has a near-zero spread)
MIN_DEVIATION_DN = 0.1
#: texels within this many texels (window radius on the surface) of an edge or of untrusted geometry may be misfits
NEAR_EDGE = 2


def near_edge(neighbours: TexelNeighbours, trusted: torch.Tensor) -> torch.Tensor:
    """(T,) bool: texels whose window of radius NEAR_EDGE on the surface (core/texel_neighbours.texel_window: the
    Surface's neighbours, across an atlas's seams) holds a cell that is not a trusted texel (off the surface, or
    untrusted geometry). trusted (T,) bool."""
    win = torch.from_numpy(texel_window(neighbours, NEAR_EDGE))
    good = (win >= 0) & trusted.cpu()[win.clamp_min(0)]
    return ~good.all(1)


def misfit_texels(
    predicted: torch.Tensor, intensity: torch.Tensor, fit_mask: torch.Tensor, estimated: torch.Tensor
) -> torch.Tensor:
    """(T,) bool: estimated texels whose RMS residual (8-bit DN, over their fitted observations and channels)
    exceeds the median texel's by MISFIT_DEVIATIONS robust deviations. predicted, intensity (P, T, 3);
    fit_mask (P, T); estimated (T,)."""
    p, t = fit_mask.to(predicted.device).nonzero(as_tuple=True)  # the fitted observations only, not (P, T) copies
    sq = ((predicted[p, t].double() - intensity.to(predicted.device)[p, t].double()) * 255.0).square().mean(-1)
    T = fit_mask.shape[1]
    count = torch.bincount(t, minlength=T).to(torch.float64)
    total = torch.zeros(T, dtype=torch.float64, device=sq.device).index_add_(0, t, sq)
    rms = torch.sqrt(total / count.clamp_min(1.0))
    valid = estimated & (count > 0)
    if int(valid.sum()) < 10:
        return torch.zeros_like(estimated)
    med = rms[valid].median()
    spread = robust_std(rms[valid]).clamp_min(MIN_DEVIATION_DN)
    return valid & (rms > med + MISFIT_DEVIATIONS * spread)
