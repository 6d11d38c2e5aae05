"""The parameters' uncertainty in the outputs: metrics.json's `uncertainty` block and the std maps.

- metrics.json `uncertainty`: per parameter (pd, ps, sigma) the median and the 95th percentile of the std over the
  estimated texels (all channels pooled); `determined_share`: the share of the estimated texels whose Ps (every
  channel) and sigma are determined to RELATIVE_PRECISION (std / value); `lobe_measured`: the estimated texels whose
  Ps and sigma come from their own observations; the sensor noise used (`noise_dn` per channel, `noise_source`).
- maps/pd_std.png, ps_std.png, sigma_std.png: the std maps in grey, 0 black, the 99th percentile of the estimated
  texels white (`pd_std_white`, ... in the metrics' `maps` entry); texels without an estimate transparent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.images import write_png
from torchrefl.fit.uncertainty import Uncertainty
from torchrefl.report.display import robust_range
from torchrefl.report.maps import rgba_map

#: the relative precision (std / value) that counts a texel's Ps and sigma as determined
RELATIVE_PRECISION = 0.1


def relative_std(ps: np.ndarray, sigma: np.ndarray, ps_std: np.ndarray, sigma_std: np.ndarray):
    """Ps's relative std (the largest over its channels; inf where Ps is 0) and sigma's, same shapes as sigma."""
    ps, ps_std = np.asarray(ps, dtype=np.float64), np.asarray(ps_std, dtype=np.float64)
    sigma, sigma_std = np.asarray(sigma, dtype=np.float64), np.asarray(sigma_std, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ps_rel = np.where(ps > 0, ps_std / ps, np.inf).max(-1)
        return ps_rel, np.where(sigma > 0, sigma_std / sigma, np.inf)


def relative_maps(ps: np.ndarray, sigma: np.ndarray, stds: dict, lobe_measured: np.ndarray):
    """(ps_rel, sigma_rel) (H, W) relative std maps for the figure, NaN where the lobe was not measured (not
    determined); ps (H, W, C), sigma (H, W) the estimate, stds the grids of uncertainty arrays (ps_std, sigma_std)."""
    ps_rel, sg_rel = relative_std(ps, sigma, stds["ps_std"], stds["sigma_std"])
    lobe = np.asarray(lobe_measured, dtype=bool)
    return np.where(lobe, ps_rel, np.nan), np.where(lobe, sg_rel, np.nan)


def uncertainty_summary(ps: torch.Tensor, sigma: torch.Tensor, unc: Uncertainty, estimated: torch.Tensor) -> dict:
    """metrics.json's `uncertainty` block (module docstring); ps (T, C), sigma (T,) the estimate, estimated (T,)."""
    e = estimated.bool()
    n = int(e.sum())

    def spread(std: torch.Tensor) -> dict:
        x = std[e].double().reshape(-1)
        if not x.numel():
            return {"median": None, "p95": None}
        return {"median": float(x.median()), "p95": float(torch.quantile(x, 0.95))}

    ps_rel, sg_rel = relative_std(ps[e].numpy(), sigma[e].numpy(), unc.ps_std[e].numpy(), unc.sigma_std[e].numpy())
    determined = int(((ps_rel <= RELATIVE_PRECISION) & (sg_rel <= RELATIVE_PRECISION)).sum())
    return {
        "pd_std": spread(unc.pd_std),
        "ps_std": spread(unc.ps_std),
        "sigma_std": spread(unc.sigma_std),
        "relative_precision": RELATIVE_PRECISION,
        "determined_share": determined / n if n else None,
        "lobe_measured": int((unc.lobe_measured & e).sum()),
        "noise_dn": [float(x) for x in unc.noise_dn],
        "noise_source": unc.noise_source,
        "model_noise_dn": None if unc.model_noise_dn is None else [float(x) for x in unc.model_noise_dn],
    }


def write_uncertainty_maps(folder: Path, mask: np.ndarray, stds: dict) -> dict:
    """Write NAME.png for each std map in stds (name -> (H, W) or (H, W, C)) into folder, grey (the channels' mean),
    0 black and the 99th percentile of the `mask` texels white; returns {NAME_white: that value}."""
    folder.mkdir(parents=True, exist_ok=True)
    mask = np.asarray(mask, dtype=bool)
    scales = {}
    for name, std in stds.items():
        std = np.asarray(std, dtype=np.float64)
        grey = std.mean(-1) if std.ndim == 3 else std
        white = robust_range(grey, mask, lower=0.0).vmax
        write_png(folder / f"{name}.png", rgba_map(grey / white, mask), bits=8)
        scales[f"{name}_white"] = white
    return scales
