"""PNG maps of the estimates and of observed / re-rendered / difference images.

All maps are RGBA PNGs on the texel grid (H, W), one pixel per texel; texels without an estimate (or, in the
light maps, without a valid observation) are transparent (alpha 0), never shown as the value 0.
- pd.png: Pd as an sRGB-encoded colour image (linear 1.0 = white, clipped above).
- ps.png: Ps as RGB, 0 black, the 99th percentile of the estimated texels white (`ps_white` in the metrics'
  `maps` entry).
- sigma.png: sigma in grey, 0 black, the 99th percentile (at most sigma_max) white (`sigma_white`).
- coverage.png: how each texel was determined (the coverage codes 1-7; 0 transparent): blue Pd with Ps, sigma
  interpolated, green Pd and Ps, sigma measured, red Pd from the upper bound only (Ps, sigma interpolated),
  magenta untrusted geometry (not fitted), yellow Pd with the object's lobe, orange misfit (no estimate), cyan Pd
  with its material's lobe fitted to its interreflected light.
- pd_std.png, ps_std.png, sigma_std.png: the parameters' std (torchrefl.report.uncertainty).
- light_NNN_{observed,rendered,diff}.png: observed and re-rendered images of a few lights
  (gamma 1/2.2 for viewing) and the signed difference (grey 128 = 0, +-16 DN full swing).
The display ranges come from torchrefl.report.display; torchrefl.report.figure draws the same maps with colour
bars and a legend (maps/figure.png, RunResult.figure).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.capture.images import write_png
from torchrefl.report.display import robust_range, srgb

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
#: The coverage codes' names in figure legends.
COVERAGE_NAMES = (
    "none: no usable observation",
    "Pd; Ps, sigma interpolated",
    "Pd, Ps, sigma measured",
    "Pd upper bound; Ps, sigma interpolated",
    "untrusted geometry (not fitted)",
    "Pd; Ps, sigma the object's lobe",
    "misfit (no estimate)",
    "Pd; Ps, sigma the material's lobe",
)


def _rgb(a: np.ndarray) -> np.ndarray:
    if a.ndim == 2:
        a = a[..., None]
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, axis=-1)
    return a


def rgba_map(rgb: np.ndarray, shown: np.ndarray) -> np.ndarray:
    """(H, W, 4) floats in [0, 1]: rgb (H, W, 1 or 3) clipped, alpha 1 on the `shown` texels and 0 elsewhere."""
    rgb = np.where(shown[..., None], np.clip(np.nan_to_num(_rgb(rgb)), 0.0, 1.0), 0.0)
    return np.concatenate([rgb, shown[..., None].astype(np.float64)], axis=-1)


def write_parameter_maps(
    folder: Path,
    mask: np.ndarray,
    pd: np.ndarray,
    ps: np.ndarray,
    sigma: np.ndarray,
    coverage: np.ndarray,
    sigma_max: float,
) -> dict:
    """Write pd/ps/sigma/coverage PNGs into folder; returns the display scales used (the values shown white)."""
    folder.mkdir(parents=True, exist_ok=True)
    mask = np.asarray(mask, dtype=bool)
    write_png(folder / "pd.png", rgba_map(srgb(_rgb(pd)), mask), bits=8)
    ps_white = robust_range(ps, np.broadcast_to(mask[..., None], np.shape(ps)), lower=0.0).vmax
    write_png(folder / "ps.png", rgba_map(_rgb(ps) / ps_white, mask), bits=8)
    sigma_white = robust_range(sigma, mask, lower=0.0, upper=sigma_max).vmax
    write_png(folder / "sigma.png", rgba_map(sigma / sigma_white, mask), bits=8)
    cov = np.zeros(mask.shape + (4,), dtype=np.uint8)
    for code, colour in COVERAGE_COLOURS.items():
        if code:
            cov[coverage == code] = colour + (255,)
    write_png(folder / "coverage.png", cov, bits=8)
    return {"ps_white": ps_white, "sigma_white": sigma_white}


def write_light_maps(folder: Path, name: str, observed: np.ndarray, rendered: np.ndarray, mask: np.ndarray) -> None:
    """observed, rendered: (H, W, 3) fractions of full range; mask (H, W) texels shown."""
    folder.mkdir(parents=True, exist_ok=True)
    mask = np.asarray(mask, dtype=bool)
    view = lambda x: rgba_map(np.clip(x, 0, 1) ** (1 / 2.2), mask)
    write_png(folder / f"{name}_observed.png", view(observed), bits=8)
    write_png(folder / f"{name}_rendered.png", view(rendered), bits=8)
    diff = (rendered - observed) * 255.0
    write_png(folder / f"{name}_diff.png", rgba_map(0.5 + diff / 32.0, mask), bits=8)
