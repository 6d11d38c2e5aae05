"""Geometry of the seed's cylindrical rig (dissertation 2.2, Fig. 2.3-2.4, 2.6).

The scanner head rotates about the vertical axis; texel column c is scanned at angle
s = angle0 + c * angle_step, row k at height t = height0 + k * height_step, and the
surface point is S(s, t) = (-r sin s, -t, -r cos s) (eq. 2.1, world y = -t).

The virtual camera and the candidate light grid ride on the head, so they co-rotate
with s. In the head frame of angle s:
    radial outward u(s) = (-sin s, 0, -cos s), up e_y = (0, 1, 0), lateral w(s) = (-cos s, 0, sin s).
A light at head-frame position [lateral, vertical, radial] is at world position
radial * u(s) + lateral * w(s) + vertical * e_y for every texel of column s; the camera
is at camera_distance * u(s) + camera_height * e_y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class CylindricalRig:
    """Scanner grid and head geometry (angles in radians inside, lengths in mm)."""

    rows: int
    columns: int
    angle0: float
    angle_step: float
    height0: float
    height_step: float
    camera_distance: float
    camera_height: float

    @property
    def grid_shape(self) -> tuple[int, int]:
        return (self.rows, self.columns)

    def angles(self) -> np.ndarray:
        """(W,) scan angle s of each column, radians."""
        return self.angle0 + self.angle_step * np.arange(self.columns)

    def heights(self) -> np.ndarray:
        """(H,) scan height t of each row, mm (world y = -t)."""
        return self.height0 + self.height_step * np.arange(self.rows)

    def covers_full_turn(self) -> bool:
        return abs(self.columns * self.angle_step - 2 * math.pi) < 1e-6

    @staticmethod
    def head_axes(s):
        """Radial u, lateral w (..., 3) for angles s (...) (numpy or torch)."""
        lib = torch if isinstance(s, torch.Tensor) else np
        zero = lib.zeros_like(s)
        u = lib.stack([-lib.sin(s), zero, -lib.cos(s)], -1)
        w = lib.stack([-lib.cos(s), zero, lib.sin(s)], -1)
        return u, w

    def head_to_world(self, s, head_position):
        """World position (..., 3) of head-frame point(s) [lateral, vertical, radial] (broadcastable
        to (..., 3), same array library as s) for scan angles s (...)."""
        u, w = self.head_axes(s)
        ey = u * 0.0
        ey[..., 1] = 1.0
        h = head_position
        return h[..., 2:3] * u + h[..., 0:1] * w + h[..., 1:2] * ey

    def camera_positions(self, s):
        """(..., 3) camera position for angles s."""
        lib = torch if isinstance(s, torch.Tensor) else np
        head = (
            lib.asarray([0.0, self.camera_height, self.camera_distance])
            if lib is np
            else torch.tensor([0.0, self.camera_height, self.camera_distance], dtype=s.dtype)
        )
        return self.head_to_world(s, head)

    def to_yaml_dict(self) -> dict:
        return {
            "grid": {
                "angle_step_deg": math.degrees(self.angle_step),
                "height_step_mm": self.height_step,
                "angle0_deg": math.degrees(self.angle0),
                "height0_mm": self.height0,
                "rows": self.rows,
                "columns": self.columns,
            },
            "camera": {"distance_mm": self.camera_distance, "height_mm": self.camera_height},
        }


def light_grid_positions(
    columns: int, rows: int, spacing: float, radial: float, center_lateral: float = 0.0, center_vertical: float = 0.0
) -> np.ndarray:
    """(rows * columns, 3) head-frame candidate positions [lateral, vertical, radial], row-major
    from the top-left (highest, most negative lateral) position."""
    lat = center_lateral + spacing * (np.arange(columns) - (columns - 1) / 2.0)
    vert = center_vertical + spacing * ((rows - 1) / 2.0 - np.arange(rows))
    L, V = np.meshgrid(lat, vert)
    return np.stack([L.ravel(), V.ravel(), np.full(L.size, float(radial))], axis=1)
