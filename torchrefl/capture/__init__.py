"""Capture kinds: each loader reads a capture folder into one Capture (Surface + Observations + truth)."""

from torchrefl.capture.base import Capture, CaptureLoader, loader_for  # noqa: E402
from torchrefl.capture.cylindrical_scan import load_scan_geometry, observation_geometry, read_scan_yaml  # noqa: E402
from torchrefl.capture.images import read_images  # noqa: E402

__all__ = [
    "Capture",
    "CaptureLoader",
    "load_scan_geometry",
    "loader_for",
    "observation_geometry",
    "read_images",
    "read_scan_yaml",
]
