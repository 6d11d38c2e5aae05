"""Measured lobes far from their measured neighbours', settled by the neighbours where the data allow it.

A texel's profiled error over sigma (torchrefl.fit.profile_search) can have two basins of nearly equal depth:
where all of a texel's highlights fall at small half-angles, a broad lobe (sigma about 0.4, Ps several times the
truth) with a low Pd repeats its diffuse reflection and its highlight about as well as the true lobe does, and
noise or the level's photon noise decides which basin wins. On the glossy vase 14 of the 510 texels of one scan
row, whose geometry all share, took the broad basin and their Pd came out 0.3-0.6 low (docs/results/vase.md).
Such a texel is an outlier in the map of measured lobes. Here a measured texel whose sigma lies more than a factor
OUTLIER_RATIO from the median sigma of the measured texels in its W x W window is evaluated at that median (Pd
and Ps in closed form) and takes it where its squared error grows by no more than its measured neighbours' own best
fits leave (the window median of their errors). That tolerance is the model's misfit level, not the sensor noise's:
the level's indirect light carries errors correlated over a texel's observations (the vase's wrong basin won by a
few DN^2, dozens of noise variances), so a texel takes its neighbours' lobe unless its highlights reject it by more
than a typical texel's whole misfit. A texel whose highlights do (a border between materials) keeps its own; a
faint lobe of a different material among others (Ps 0.02 against 0.3) may not, and its Pd barely depends on it.
"""

from __future__ import annotations

import math
from typing import Callable

import torch

from torchrefl.core.surface import Surface
from torchrefl.core.texel_neighbours import window_median

#: a measured sigma further than this factor from its measured neighbours' median is an outlier of the lobe map
OUTLIER_RATIO = 1.5


def neighbour_median(surface: Surface, values: torch.Tensor, measured: torch.Tensor, window: int) -> torch.Tensor:
    """(T,) the median of values (T,) over the measured (T,) texels in each measured texel's W x W window on the
    surface (itself included; core/texel_neighbours.window_median); NaN at the texels that are not measured."""
    measured = measured.cpu()
    texels = torch.nonzero(measured)[:, 0]
    med, _ = window_median(surface.neighbours, values.detach().cpu().double()[:, None], measured, texels, window)
    out = torch.full((surface.num_texels,), float("nan"), dtype=values.dtype)
    out[texels] = med[:, 0].to(values.dtype)
    return out.to(values.device)


def agree_with_neighbours(
    surface: Surface,
    sigma: torch.Tensor,
    error: torch.Tensor,
    measured: torch.Tensor,
    window: int,
    evaluate: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]],
) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Which measured texels take their neighbours' lobe, and (pd, ps, sigma, error) there.

    sigma, error (T,): each texel's lobe width and the squared error of its observations with it; measured (T,)
    bool: the texels whose lobe comes from their own highlights; evaluate(sigma (T,)) -> (pd (T, 3), ps (T, C),
    error (T,)) with Pd and Ps in closed form at one sigma per texel. Returns adopt (T,) bool and the evaluated
    (pd, ps, sigma, error) (meaningful where adopt)."""
    measured = measured & torch.isfinite(sigma) & torch.isfinite(error)
    ref = neighbour_median(surface, sigma.log(), measured, window).exp()
    tolerance = neighbour_median(surface, error, measured, window)
    outlier = measured & torch.isfinite(ref) & ((sigma / ref).log().abs() > math.log(OUTLIER_RATIO))
    ref = torch.where(outlier, ref, sigma)
    pd, ps, err = evaluate(ref)
    adopt = outlier & (err <= error + tolerance)
    return adopt, (pd, ps, ref, err)


def settle_outliers(surface, pd, ps, sigma, error, measured, window: int, evaluate) -> tuple:
    """(pd (T, 3), ps (T, C), sigma (T,), adopt (T,)): the lobes with agree_with_neighbours' choice applied (Pd and Ps
    from evaluate where a texel took its neighbours' sigma), in the given tensors' dtypes."""
    adopt, (pd_c, ps_c, sg_c, _) = agree_with_neighbours(surface, sigma, error, measured, window, evaluate)
    pd = torch.where(adopt[:, None], pd_c.to(pd.dtype), pd)
    ps = torch.where(adopt[:, None], ps_c.to(ps.dtype), ps)
    sigma = torch.where(adopt, sg_c.to(sigma.dtype), sigma)
    return pd, ps, sigma, adopt
