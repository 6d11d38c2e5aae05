"""Geometry: range-image preprocessing and the range mesh."""
