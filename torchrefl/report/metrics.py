"""Metrics written to metrics.json.

Image differences are on a 0-255 scale of the sensor's full range ("8bit": a 16-bit value v
counts as v / 257), so they compare with the seed's Table 5.2: the mean of |synthetic - real|,
the variance of the signed difference, and the RMSE, over the given observations and channels.
"""

from __future__ import annotations

import json
import math

import torch


def image_difference(pred: torch.Tensor, measured: torch.Tensor, mask: torch.Tensor) -> dict:
    """pred, measured: (P, T, 3) fractions of full range; mask: (P, T) bool."""
    d = ((pred - measured) * 255.0)[mask].double().reshape(-1)
    if d.numel() == 0:
        return {"mean_abs_diff_8bit": None, "var_diff_8bit": None, "rmse_8bit": None, "count": 0}
    return {
        "mean_abs_diff_8bit": float(d.abs().mean()),
        "var_diff_8bit": float(d.var(unbiased=False)),
        "rmse_8bit": float(torch.sqrt((d * d).mean())),
        "count": int(d.numel()),
    }


def _median(x: torch.Tensor):
    return float(x.median()) if x.numel() else None


def ground_truth_errors(pd, ps, sigma, truth: dict, estimated: torch.Tensor, spec_observed: torch.Tensor) -> dict:
    """Parameter errors against the truth.

    pd (T, 3), ps (T, C), sigma (T,) estimates; truth dict with pd (T, 3), ps (T, 3), sigma (T,);
    estimated (T,) texels with an estimate (RMSEs over them); spec_observed (T,) texels seen in
    T_spec at least twice (relative errors over them; Ps compared on the channel mean).
    """
    pd, ps, sigma = pd.double(), ps.double(), sigma.double()
    tpd, tps, tsg = truth["pd"].double(), truth["ps"].double(), truth["sigma"].double()
    if ps.shape[-1] != tps.shape[-1]:
        tps = tps.mean(-1, keepdim=True)
    e = estimated
    s = spec_observed & estimated
    rmse = lambda a, b: float(torch.sqrt(((a - b) ** 2).mean())) if a.numel() else None
    ps_grey, tps_grey = ps.mean(-1), tps.mean(-1)
    glossy = s & (tps_grey > 1e-3)  # relative errors only where the truth has a specular lobe
    rel_ps = ((ps_grey - tps_grey).abs() / tps_grey.clamp_min(1e-12))[glossy]
    rel_sg = ((sigma - tsg).abs() / tsg.clamp_min(1e-12))[glossy]
    return {
        "pd_rmse": rmse(pd[e], tpd[e]),
        "ps_rmse": rmse(ps[e], tps[e]),
        "sigma_rmse": rmse(sigma[e], tsg[e]),
        "ps_median_rel_err": _median(rel_ps),
        "sigma_median_rel_err": _median(rel_sg),
        "pd_max_abs_err": float((pd[e] - tpd[e]).abs().max()) if e.any() else None,
        "texels_estimated": int(e.sum()),
        "texels_spec_observed_twice": int(s.sum()),
    }


def finite_or_none(x):
    """JSON-safe float."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def json_safe(value):
    """`value` with every NaN or infinite float (at any depth) replaced by None: what strict JSON can hold."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, float):
        return finite_or_none(value)
    return value


def strict_json(value) -> str:
    """Indented JSON with no NaN or Infinity (non-finite numbers become null)."""
    return json.dumps(json_safe(value), indent=2, allow_nan=False)
