"""The shape of the diffuse part, from the diffuse-only observations: Minnaert's exponent k.

On T_diff observations (far from every highlight: dissertation eq. 2.20) the local model is
    i_ptc = Pd_tc A_ptc(k),   A(k) = A(1) (cos_l cos_v)^(k - 1)     (torchrefl.core.brdf.diffuse_term)
with A(1) the Lambertian factor of the local terms. For a given k the least-squares Pd of every texel
and channel is closed form, Pd_tc = sum_p A i / sum_p A^2, so the squared error left,
    E(k) = sum (i - Pd A)^2 = sum i^2 - sum_tc (sum_p A i)^2 / sum_p A^2,
depends on k alone. A grid over [low, high] brackets its minimum and a golden-section search refines
it. One k for the object: the parameter the data pins best (hundreds of thousands of observations),
while a per-texel k would trade off against Pd.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from torchrefl.core.brdf import COS_EPS
from torchrefl.errors import FitError
from torchrefl.transport.local import LocalTerms

K_LOW, K_HIGH = 0.5, 2.0
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass
class DiffuseShape:
    """k: the fitted exponent; mse_lambert_8bit / mse_8bit: mean squared residual of the T_diff
    observations (8-bit DN^2, per channel) with k = 1 and with the fitted k; observations: how many."""

    k: float
    mse_lambert_8bit: float
    mse_8bit: float
    observations: int

    @property
    def note(self) -> str:
        return (
            f"diffuse: Minnaert k = {self.k:.4f} fitted on {self.observations} diffuse-only observations "
            f"(mean squared residual {self.mse_8bit:.4g} DN^2 against {self.mse_lambert_8bit:.4g} for Lambert, k = 1)"
        )

    def as_dict(self) -> dict:
        return {
            "k": self.k,
            "mse_lambert_8bit": self.mse_lambert_8bit,
            "mse_8bit": self.mse_8bit,
            "observations": self.observations,
        }


def fit_minnaert_exponent(
    terms: LocalTerms,
    intensity: torch.Tensor,
    mask: torch.Tensor,
    *,
    low: float = K_LOW,
    high: float = K_HIGH,
    grid: int = 31,
    tol: float = 1e-4,
) -> DiffuseShape:
    """Minnaert's k minimising E(k) (module docstring) over the observations in mask (P, T).

    terms: Lambertian local terms (diffuse_exponent 1); intensity (P, T, 3) measured.
    Raises FitError when mask selects no observation.
    """
    if terms.diffuse_exponent != 1.0:
        raise ValueError("fit_minnaert_exponent needs Lambertian local terms (diffuse_exponent 1)")
    p, t = torch.nonzero(mask, as_tuple=True)
    if p.numel() == 0:
        raise FitError(
            "reflectance.diffuse: minnaert with a fitted k needs diffuse-only (T_diff) observations and "
            "the capture has none; set reflectance.minnaert_k to a value"
        )
    a = terms.diffuse[p, t].double()  # (N, 3)
    i = intensity[p, t].double()
    log_lv = (
        torch.log(terms.cos_l[p, t].double().clamp_min(COS_EPS))
        + torch.log(terms.cos_v[p, t].double().clamp_min(COS_EPS))
    )[:, None]
    T = int(mask.shape[1])
    sum_ii = float((i * i).sum())
    count = float(i.numel())

    def error(k: float) -> float:
        ak = a * torch.exp((k - 1.0) * log_lv)
        s_ai = torch.zeros(T, 3, dtype=torch.float64).index_add_(0, t, ak * i)
        s_aa = torch.zeros(T, 3, dtype=torch.float64).index_add_(0, t, ak * ak)
        used = s_aa > 0
        return (sum_ii - float((s_ai[used] ** 2 / s_aa[used]).sum())) / count * 255.0**2

    ks = torch.linspace(low, high, grid, dtype=torch.float64).tolist()
    errs = [error(k) for k in ks]
    j = min(range(grid), key=errs.__getitem__)
    lo, hi = ks[max(j - 1, 0)], ks[min(j + 1, grid - 1)]
    x1, x2 = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
    e1, e2 = error(x1), error(x2)
    while hi - lo > tol:
        if e1 < e2:
            hi, x2, e2 = x2, x1, e1
            x1 = hi - _GOLDEN * (hi - lo)
            e1 = error(x1)
        else:
            lo, x1, e1 = x1, x2, e2
            x2 = lo + _GOLDEN * (hi - lo)
            e2 = error(x2)
    k = 0.5 * (lo + hi)
    return DiffuseShape(k=float(k), mse_lambert_8bit=error(1.0), mse_8bit=error(k), observations=int(p.numel()))
