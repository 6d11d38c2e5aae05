"""The scale check (capture.scale_check) of a cylindrical_scan folder, about the rotation axis.

The range image measures distances from the axis, and only those: the heights come from the grid. So
the object's radius is its largest range, and the lengths it is compared with are measured about the
axis too: camera.distance_mm, each light's horizontal distance from the axis (a head-frame position
[lateral, vertical, radial] is hypot(lateral, radial) from it) and grid.height_step_mm (a sampling step).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.capture.scale_check import ObjectSize, Reference, ScaleCheck, check_scale
from torchrefl.capture.scan_yaml import SCAN_YAML
from torchrefl.config_loading import read_yaml_mapping
from torchrefl.errors import CaptureError


def head_distances(head_positions) -> np.ndarray:
    """(P,) horizontal distance from the rotation axis of head-frame positions (P, 3) [lateral, vertical, radial]."""
    h = np.asarray(head_positions, dtype=np.float64).reshape(-1, 3)
    return np.hypot(h[:, 0], h[:, 2])


def scan_scale_check(r_mm: np.ndarray, doc: dict, folder: Path) -> ScaleCheck:
    """check_scale of the range image r_mm (H, W) (mm, NaN = nothing) against the scan.yaml `doc` of `folder`."""
    where = folder / SCAN_YAML
    spec = doc.get("range", {})
    range_file = folder / spec.get("file", "range.npy")
    if "scale_mm" in spec:
        fix = (
            f"multiply range.scale_mm ({spec['scale_mm']:g}) in {where} by {{factor:g}}, or convert {range_file} to mm"
        )
    else:
        fix = f"give range.scale_mm: {{factor:g}} (mm per stored unit) in {where}, or convert {range_file} to mm"
    obj = ObjectSize(float(np.nanmax(r_mm)), str(range_file), "the ranges", fix, "the rotation axis")
    raw_lights = read_yaml_mapping(where, CaptureError).get("lights")
    lights_file = folder / raw_lights if isinstance(raw_lights, str) else where
    refs = [
        Reference.of("camera", str(where), "camera.distance_mm", doc["camera"]["distance_mm"]),
        Reference.of("step", str(where), "grid.height_step_mm", doc["grid"]["height_step_mm"]),
        Reference.of(
            "light",
            str(lights_file),
            "lights[{i}].position_mm",
            head_distances([e["position_mm"] for e in doc["lights"]]),
        ),
    ]
    return check_scale(obj, refs)
