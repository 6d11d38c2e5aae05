"""PNG maps of the estimates and of observed / re-rendered / difference images.

All maps are on the texel grid (H, W); texels without an estimate are black.
- pd.png: Pd as RGB (1.0 = full white, clipped above).
- ps.png: Ps as RGB scaled so the 99th percentile is white (scale in the metrics' `maps` entry).
- sigma.png: sigma in grey, 0 = black, sigma_max = white.
- coverage.png: how each texel was determined (the coverage codes 0-7): black none, blue Pd with Ps, sigma
  interpolated, green Pd and Ps, sigma measured, red Pd from the upper bound only (Ps, sigma interpolated),
  magenta untrusted geometry (not fitted), yellow Pd with the object's lobe, orange misfit (no estimate), cyan Pd
  with its material's lobe fitted to its interreflected light.
- light_NNN_{observed,rendered,diff}.png: observed and re-rendered images of a few lights
  (gamma 1/2.2 for viewing) and the signed difference (grey 128 = 0, +-16 DN full swing).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.capture.images import write_png

COVERAGE_COLOURS = {
    0: (0, 0, 0),
    1: (40, 90, 220),
    2: (40, 200, 60),
    3: (220, 50, 40),
    4: (200, 40, 200),
    5: (230, 200, 40),
    6: (255, 140, 0),
    7: (40, 210, 210),
}
COVERAGE_NAMES = (
    "none",
    "Pd, spec interpolated",
    "Pd + spec measured",
    "Pd bound",
    "untrusted geometry",
    "object's lobe",
    "misfit",
    "material's lobe",
)


def _rgb(a: np.ndarray) -> np.ndarray:
    if a.ndim == 2:
        a = a[..., None]
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, axis=-1)
    return a


def write_parameter_maps(
    folder: Path,
    mask: np.ndarray,
    pd: np.ndarray,
    ps: np.ndarray,
    sigma: np.ndarray,
    coverage: np.ndarray,
    sigma_max: float,
) -> dict:
    """Write pd/ps/sigma/coverage PNGs into folder; returns the display scales used."""
    folder.mkdir(parents=True, exist_ok=True)
    m = mask[..., None]
    write_png(folder / "pd.png", np.clip(_rgb(pd) * m, 0, 1), bits=8)
    ps_scale = float(np.percentile(ps[mask], 99)) if mask.any() else 1.0
    ps_scale = ps_scale if ps_scale > 0 else 1.0
    write_png(folder / "ps.png", np.clip(_rgb(ps) / ps_scale * m, 0, 1), bits=8)
    write_png(folder / "sigma.png", np.clip(_rgb(sigma / sigma_max) * m, 0, 1), bits=8)
    cov = np.zeros(mask.shape + (3,), dtype=np.uint8)
    for code, colour in COVERAGE_COLOURS.items():
        cov[coverage == code] = colour
    write_png(folder / "coverage.png", cov, bits=8)
    return {"ps_white": ps_scale, "sigma_white": sigma_max}


def write_light_maps(folder: Path, name: str, observed: np.ndarray, rendered: np.ndarray, mask: np.ndarray) -> None:
    """observed, rendered: (H, W, 3) fractions of full range; mask (H, W) texels shown."""
    folder.mkdir(parents=True, exist_ok=True)
    m = mask[..., None]
    view = lambda x: np.clip(np.clip(x, 0, 1) ** (1 / 2.2) * m, 0, 1)
    write_png(folder / f"{name}_observed.png", view(observed), bits=8)
    write_png(folder / f"{name}_rendered.png", view(rendered), bits=8)
    diff = (rendered - observed) * 255.0
    write_png(folder / f"{name}_diff.png", np.clip(0.5 + diff / 32.0, 0, 1) * m + 0.5 * (1 - m), bits=8)
