"""How many fresh photon traces the photon level's final images average beside the kept cache.

The final images (re-rendered, held-out) carry the photon noise of the caches they are predicted with; averaging n
independent traces divides its variance by n. One trace's variance per observation is measured from the last
averaged refresh: its cache is the mean of two independent traces a and b, so cache - b = (a - b) / 2 has half a
trace's variance. The images need photon noise small beside their own noise (the residuals' robust spread): the
final images average the fewest fresh traces that keep the photon variance at most PHOTON_NOISE_SHARE of it (so it
adds at most about 5 % to the noise's std), at most FINAL_TRACES - 1 of them, each weighted by its traces.
"""

from __future__ import annotations

import math
from typing import Optional

import torch

from torchrefl.core.robust import robust_std

#: caches the final images average at most: the kept one and fresh traces
FINAL_TRACES = 4
#: the final images' photon variance may be at most this share of their noise variance
PHOTON_NOISE_SHARE = 0.1


def trace_variance(averaged: torch.Tensor, newer: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(3,) one trace's photon variance per observation and channel in DN^2: 2 mean((averaged - newer)^2) over the
    observations mask (P, T) of the images averaged (P, T, 3), predicted with a two-trace cache, and newer, with its
    newer trace alone (a parameter change between the traces counts as noise: an overestimate)."""
    d = ((averaged - newer) * 255.0)[mask].double()
    return 2.0 * d.square().mean(0) if len(d) else torch.full((3,), float("inf"), dtype=torch.float64)


def image_variance(images: torch.Tensor, intensity: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(3,) the images' noise variance per channel in DN^2: the robust spread of the residuals over mask (P, T)."""
    r = ((images - intensity) * 255.0)[mask].double()
    return robust_std(r, 0).square() if len(r) else torch.zeros(3, dtype=torch.float64)


def fresh_traces(single: Optional[torch.Tensor], noise: Optional[torch.Tensor], kept_traces: int) -> int:
    """The fresh traces to average with a kept cache of kept_traces traces: the fewest m with single / (kept + m) at
    most PHOTON_NOISE_SHARE x noise in every channel (single, noise (3,) DN^2: trace_variance, image_variance), at
    most FINAL_TRACES - 1; that many where either is unknown (None)."""
    most = FINAL_TRACES - 1
    if single is None or noise is None:
        return most
    ratio = float((single / (PHOTON_NOISE_SHARE * noise.clamp_min(1e-12))).max())
    if not ratio < float("inf"):
        return most
    return min(max(math.ceil(ratio) - kept_traces, 0), most)
