"""Display scales for maps a person looks at: robust colour ranges, sRGB encoding, the no-estimate background.

One place for the choices every figure and PNG map shares (torchrefl.report.figure, torchrefl.report.maps):
- a colour range from percentiles of the texels a map describes, so that a few outliers do not squash the rest
  into one colour, clipped to the quantity's physical limits where it has them, and widened around its level
  where the map is (nearly) constant, so that a constant map shows as one colour rather than as float noise;
- Pd, an albedo in [0, 1], shown as an sRGB-encoded colour image (kornia's linear_rgb_to_rgb);
- texels without an estimate shown on a neutral, hatched background (never as the value 0, and not to be taken
  for a grey albedo).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from kornia.color import linear_rgb_to_rgb

#: Texels without an estimate in figures: a neutral light grey (RGB fractions), unlike any colour map's ends,
#: hatched with darker grey lines.
BACKGROUND = (0.85, 0.85, 0.85)
HATCH = "///"
HATCH_COLOUR = (0.6, 0.6, 0.6)
#: Percentiles of the described texels that bound a colour range.
PERCENTILES = (1.0, 99.0)
#: A map whose percentile spread is below this fraction of its level (or below MIN_SPAN) is shown as constant.
FLAT = 1e-3
#: The smallest colour range for a map at level 0 (the map's unit: albedo, rad).
MIN_SPAN = 1e-6


@dataclass(frozen=True)
class DisplayRange:
    """The values shown at the two ends of a colour scale; below / above: some described values lie outside it
    (a colour bar draws them as arrows: `extend`); flat: the map is constant (to FLAT), shown at the middle."""

    vmin: float
    vmax: float
    below: bool = False
    above: bool = False
    flat: bool = False

    @property
    def level(self) -> float:
        """The value at the middle of the scale."""
        return 0.5 * (self.vmin + self.vmax)

    @property
    def extend(self) -> str:
        """matplotlib's colorbar `extend`: which ends hold clipped values."""
        return {(False, False): "neither", (True, False): "min", (False, True): "max"}.get(
            (self.below, self.above), "both"
        )


def robust_range(
    values: np.ndarray,
    mask: np.ndarray | None = None,
    percentiles: tuple[float, float] = PERCENTILES,
    lower: float | None = None,
    upper: float | None = None,
) -> DisplayRange:
    """The colour range of `values` over the texels in `mask` (all finite values where None): the given
    percentiles, clipped to the physical limits [lower, upper] where given. A (nearly) constant map gets a range
    centred on its level, so every texel takes the scale's middle colour. No described texel: [lower or 0,
    upper or 1]."""
    v = np.asarray(values, dtype=np.float64)
    if mask is not None:
        v = v[np.asarray(mask, dtype=bool)]
    v = v[np.isfinite(v)]
    if v.size == 0:
        lo = 0.0 if lower is None else float(lower)
        return DisplayRange(lo, lo + 1.0 if upper is None else float(upper))
    lo, hi = (float(x) for x in np.percentile(v, percentiles))
    lo = lo if lower is None else max(lo, float(lower))
    hi = hi if upper is None else min(hi, float(upper))
    level = 0.5 * (lo + hi)
    span = max(FLAT * abs(level), MIN_SPAN)
    flat = hi - lo < span
    if flat:
        lo, hi = level - span / 2, level + span / 2
    return DisplayRange(lo, hi, below=bool((v < lo).any()), above=bool((v > hi).any()), flat=flat)


def srgb(linear: np.ndarray) -> np.ndarray:
    """(..., 3) linear RGB in [0, 1] (clipped) as sRGB-encoded fractions in [0, 1], the encoding screens expect."""
    a = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    flat = torch.from_numpy(np.ascontiguousarray(a.reshape(-1, 3).T[:, :, None]))
    return np.clip(linear_rgb_to_rgb(flat)[:, :, 0].T.numpy().reshape(a.shape), 0.0, 1.0)


def show_no_data(ax) -> None:
    """Give a matplotlib Axes the no-estimate background: texels drawn transparent (alpha 0 or a colour map's
    transparent `bad` colour) show it."""
    ax.set_facecolor(BACKGROUND)
    ax.patch.set_hatch(HATCH)
    ax.patch.set_hatchcolor(HATCH_COLOUR)
