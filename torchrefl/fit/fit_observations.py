"""Why the fit has nothing to fit: the observations each of the fit's filters removes.

fit.observe builds the fit's mask as obs.valid & (n.v > reflectance.min_cos_view) & (n.l >
reflectance.min_cos_light) & not held out (fit.holdout). `require_fit_observations` is called with those
masks right after; when none is left it raises FitError naming each filter and how many it removed.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchrefl.errors import FitError


@dataclass(frozen=True)
class FilterCount:
    name: str
    removed: int


def filter_counts(
    valid: torch.Tensor,
    cos_v: torch.Tensor,
    cos_l: torch.Tensor,
    held: torch.Tensor,
    min_cos_view: float,
    min_cos_light: float,
) -> list[FilterCount]:
    """valid (P, T) the capture's usable observations; cos_v (T,) or (P, T); cos_l (P, T); held (P,) lights held out."""
    shape = valid.shape
    return [
        FilterCount(
            "unusable in the capture (unseen, unlit, shadowed, saturated, edge or crease)", int((~valid).sum())
        ),
        FilterCount(
            f"grazing view (n.v <= reflectance.min_cos_view {min_cos_view:g})",
            int((cos_v <= min_cos_view).expand(shape).sum()),
        ),
        FilterCount(
            f"grazing light (n.l <= reflectance.min_cos_light {min_cos_light:g})", int((cos_l <= min_cos_light).sum())
        ),
        FilterCount(f"held out (fit.holdout: {int(held.sum())} lights)", int(held[:, None].expand(shape).sum())),
    ]


def require_fit_observations(
    fit_mask: torch.Tensor,
    valid: torch.Tensor,
    cos_v: torch.Tensor,
    cos_l: torch.Tensor,
    held: torch.Tensor,
    min_cos_view: float,
    min_cos_light: float,
    source: str,
) -> None:
    """FitError saying which filter removed how many observations when fit_mask (P, T) selects none."""
    if bool(fit_mask.any()):
        return
    counts = filter_counts(valid, cos_v, cos_l, held, min_cos_view, min_cos_light)
    reasons = "; ".join(f"{c.name}: {c.removed}" for c in counts if c.removed)
    raise FitError(
        f"nothing to fit in {source}: none of the {fit_mask.numel()} observations is left ({reasons}; "
        "an observation may fall under several filters)"
    )
