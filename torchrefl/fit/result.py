"""What the fit of one capture returns."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Optional

import torch

if TYPE_CHECKING:
    from torchrefl.fit.uncertainty import Uncertainty


@dataclass
class DiffuseModel:
    """The diffuse part: lambert (k = 1) or minnaert with its exponent k, fitted or given."""

    model: str = "lambert"
    k: float = 1.0
    fitted: bool = False
    note: dict = field(default_factory=dict)  # the exponent fit's own numbers (minnaert, fitted)

    def as_dict(self) -> dict:
        out = {"model": self.model, "k": self.k}
        if self.model != "lambert":
            out.update(self.note, fitted=self.fitted)
        return out


@dataclass
class FitResult:
    """Per-texel estimate (T texels) and what the fit of a capture with P lights saw and did."""

    pd: torch.Tensor  # (T, 3)
    ps: torch.Tensor  # (T, C), C in {1, 3}
    sigma: torch.Tensor  # (T,)
    predicted: torch.Tensor  # (P, T, 3) the model's images at the estimate
    fit_mask: torch.Tensor  # (P, T) observations fitted
    eval_mask: torch.Tensor  # (P, T) held-out observations evaluated: of the estimated texels only
    counts: dict  # T_diff, T_spec, T_none: (T,) observations per class
    coverage: torch.Tensor  # (T,) how each texel was determined (report.maps codes)
    estimated: torch.Tensor  # (T,) bool: texels with an estimate
    init_counts: dict  # pd_closed_form, spec_closed_form, spec_known: texel counts of the start
    history: list  # loss per evaluation
    optimizer: str  # the refinement optimiser used (fit.optimizer, or lbfgs for lm where texels are coupled)
    level: str  # the transport level used
    model_reason: str  # why that level, and what it precomputed
    diffuse: DiffuseModel
    model_numbers: dict = field(default_factory=dict)  # auto's measured interreflection
    photon: dict | None = None  # the photon level's per-refresh image differences and cache statistics
    misfit: int = 0  # texels without an estimate because the fitted model cannot explain them (fit.misfit)
    uncertainty: Optional[Uncertainty] = None  # the std of every parameter (torchrefl.fit.uncertainty)
    holdout_unestimated: int = 0  # held-out observations of texels without an estimate (not evaluated)
