"""Fitting: observation classes, closed forms, interpolation, parameter tensors, refinement."""
