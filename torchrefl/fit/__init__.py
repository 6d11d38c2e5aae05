"""Fitting: observation classes, closed forms, interpolation, parameter tensors, refinement."""

from torchrefl.fit.pipeline import fit_capture, level_inputs  # noqa: E402
from torchrefl.fit.result import FitResult  # noqa: E402

__all__ = ["FitResult", "fit_capture", "level_inputs"]
