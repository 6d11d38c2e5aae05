"""Classification of every (light, texel) observation (dissertation 2.4.3-2.4.4, 3.2).

T_diff: theta_h > theta_th1 (eq. 2.20): only diffuse reflection is observed.
T_spec: theta_h <= theta_th2 (eq. 2.21): strong specular reflection is observed.
T_none: neither. INVALID: not usable (unseen, unlit, shadowed, saturated, held out).
"""

from __future__ import annotations

import math

import torch

INVALID, T_DIFF, T_SPEC, T_NONE = 0, 1, 2, 3
CLASS_NAMES = {INVALID: "invalid", T_DIFF: "T_diff", T_SPEC: "T_spec", T_NONE: "T_none"}


def classify(
    theta_h: torch.Tensor, valid: torch.Tensor, theta_diffuse_deg: float = 60.0, theta_specular_deg: float = 20.0
) -> torch.Tensor:
    """(P, T) int8 class codes from half-angles theta_h (P, T) radians and the validity mask (P, T)."""
    th1 = math.radians(theta_diffuse_deg)
    th2 = math.radians(theta_specular_deg)
    cls = torch.full(theta_h.shape, T_NONE, dtype=torch.int8)
    cls[theta_h > th1] = T_DIFF
    cls[theta_h <= th2] = T_SPEC
    cls[~valid] = INVALID
    return cls


def class_counts(cls: torch.Tensor) -> dict:
    """Per-texel counts (T,) of each class, keyed by class name."""
    return {name: (cls == code).sum(dim=0) for code, name in CLASS_NAMES.items()}
