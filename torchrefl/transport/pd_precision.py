"""How precisely the observations determine Pd: the outer loop's convergence test.

The images are linear in Pd given the other parameters and the cached indirect light (transport.texel_model), so
each texel's Pd has, per channel, the information sum over its fitted observations of (255 dI/dPd)^2 / s^2 with s
the residuals' robust noise (1.4826 x their median absolute deviation, in 8-bit DN); its std is one over the
square root (the lobe held at its value). An outer iteration that moves Pd by less than the median of these stds
changes nothing the data can tell apart.
"""

from __future__ import annotations

from typing import Callable

import torch

from torchrefl.core.robust import robust_std


def median_pd_std(model: Callable, pd, ps, sigma, intensity: torch.Tensor, mask: torch.Tensor) -> float:
    """The median over the texels with a fitted observation (mask (P, T)) and channels of Pd's std: model (pd (T, 3),
    ps, sigma) -> (P, T, 3) linear in pd; intensity (P, T, 3). inf where no texel has one."""
    with torch.no_grad():
        without = model(torch.zeros_like(pd), ps, sigma)
        slope = model(torch.ones_like(pd), ps, sigma) - without
        r = ((without + pd[None] * slope - intensity) * 255.0)[mask]  # (N, 3): linear in pd, no third evaluation
        slope = slope * 255.0
        if not len(r):
            return float("inf")
        noise = robust_std(r, 0).clamp_min(1e-3)  # (3,)
        info = (slope.square() * mask[..., None]).sum(0) / noise.square()  # (T, 3)
        seen = mask.any(0)
        return float(info[seen].clamp_min(1e-30).rsqrt().median())
