"""Robust spread: the normal-consistent median absolute deviation."""

from __future__ import annotations

import torch

#: the normal-distribution consistency factor of the median absolute deviation
MAD_SCALE = 1.4826


def robust_std(x: torch.Tensor, dim: int = 0) -> torch.Tensor:
    """MAD_SCALE x the median absolute deviation of x along dim (the std of a normal sample, robust to outliers);
    torch's median (the lower one for an even count)."""
    return MAD_SCALE * (x - x.median(dim, keepdim=True).values).abs().median(dim).values
