"""The rig model: light-grid positions and head-frame positions <-> GRBL machine coordinates,
soft limits checked before anything is sent, and the G-code that switches the light.

Head frame (see the cylindrical_scan contract): [lateral, vertical, radial] in mm; the gantry moves
the light laterally and vertically in a plane at a fixed radial distance. Grid index (i, j): i is
the column (lateral, left to right), j the row (vertical, top to bottom), flat index j*columns + i,
the layout of torchrefl.capture.cylindrical_rig.light_grid_positions.
"""

from __future__ import annotations

import numpy as np

from torchrefl.errors import RigError
from torchrefl.rig.settings import AxisSettings, RigSettings


class RigModel:
    """Maps head-frame light positions (and an optional turntable angle) to axis coordinates."""

    def __init__(self, settings: RigSettings):
        self.s = settings
        self.grid = settings.grid

    # ---------------------------------------------------------------- grid

    def grid_position(self, i: int, j: int) -> np.ndarray:
        """(3,) float64 head-frame position [lateral, vertical, radial] of grid column i, row j."""
        g = self.grid
        if not (0 <= int(i) < g.columns and 0 <= int(j) < g.rows):
            raise RigError(
                f"grid index ({i}, {j}) outside the {g.columns} x {g.rows} light grid "
                f"(column 0..{g.columns - 1}, row 0..{g.rows - 1})"
            )
        lat = g.center_lateral_mm + g.spacing_mm * (int(i) - (g.columns - 1) / 2.0)
        vert = g.center_vertical_mm + g.spacing_mm * ((g.rows - 1) / 2.0 - int(j))
        return np.array([lat, vert, self.s.radial_mm], dtype=np.float64)

    def grid_positions(self) -> np.ndarray:
        """(rows * columns, 3) all grid positions, flat index j*columns + i."""
        g = self.grid
        return np.stack([self.grid_position(i, j) for j in range(g.rows) for i in range(g.columns)])

    def grid_index(self, position_mm, tol_mm: float = 1e-3) -> tuple[int, int] | None:
        """(i, j) of the grid node at position_mm (3,), or None when it is not on the grid."""
        g = self.grid
        p = np.asarray(position_mm, dtype=np.float64)
        fi = (p[0] - g.center_lateral_mm) / g.spacing_mm + (g.columns - 1) / 2.0
        fj = (g.rows - 1) / 2.0 - (p[1] - g.center_vertical_mm) / g.spacing_mm
        i, j = int(round(fi)), int(round(fj))
        if not (0 <= i < g.columns and 0 <= j < g.rows):
            return None
        if np.abs(self.grid_position(i, j) - p).max() > tol_mm:
            return None
        return i, j

    # ---------------------------------------------------------------- axes

    @staticmethod
    def _to_machine(ax: AxisSettings, value: float) -> float:
        return ax.origin_mm + ax.sign * float(value)

    @staticmethod
    def _from_machine(ax: AxisSettings, mpos: float) -> float:
        return (float(mpos) - ax.origin_mm) / ax.sign

    def _axis_index(self, letter: str) -> int:
        return "XYZA".index(letter)

    def head_to_axes(self, position_mm, angle_deg: float | None = None) -> dict:
        """{'X': mm, 'Y': mm[, turntable letter: deg]} machine coordinates for a head-frame position (3,).
        The radial coordinate must equal radial_mm (the light plane is fixed)."""
        p = np.asarray(position_mm, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise RigError(f"light position {position_mm!r}: expected 3 finite numbers [lateral, vertical, radial] mm")
        if abs(p[2] - self.s.radial_mm) > self.s.position_tolerance_mm:
            raise RigError(
                f"light position {p.tolist()}: radial {p[2]} mm is not the gantry plane's radial_mm "
                f"{self.s.radial_mm} (the gantry moves laterally and vertically only)"
            )
        out = {
            self.s.lateral.axis: self._to_machine(self.s.lateral, p[0]),
            self.s.vertical.axis: self._to_machine(self.s.vertical, p[1]),
        }
        if angle_deg is not None:
            if not self.s.turntable.enabled:
                raise RigError("a turntable angle was given but the rig settings define no turntable axis")
            out[self.s.turntable.axis] = self._to_machine(self.s.turntable, angle_deg)
        return out

    def axes_to_head(self, mpos) -> np.ndarray:
        """(3,) head-frame position reached, from GRBL's MPos (X, Y, Z[, A])."""
        m = list(mpos)
        lat = self._from_machine(self.s.lateral, m[self._axis_index(self.s.lateral.axis)])
        vert = self._from_machine(self.s.vertical, m[self._axis_index(self.s.vertical.axis)])
        return np.array([lat, vert, self.s.radial_mm], dtype=np.float64)

    def axes_to_angle(self, mpos) -> float | None:
        if not self.s.turntable.enabled:
            return None
        return self._from_machine(self.s.turntable, list(mpos)[self._axis_index(self.s.turntable.axis)])

    def check_travel(self, axes: dict, what: str = "move") -> None:
        """RigError naming the axis and the limits when a target lies outside the configured travel."""
        by_letter = {
            self.s.lateral.axis: ("lateral", self.s.lateral),
            self.s.vertical.axis: ("vertical", self.s.vertical),
        }
        if self.s.turntable.enabled:
            by_letter[self.s.turntable.axis] = ("turntable", self.s.turntable)
        for letter, value in axes.items():
            name, ax = by_letter[letter]
            if not (ax.min_mm - 1e-9 <= value <= ax.max_mm + 1e-9):
                raise RigError(
                    f"{what}: {name} axis {letter} target {value:.3f} is outside the travel "
                    f"[{ax.min_mm}, {ax.max_mm}] set by rig settings {name}.min_mm/max_mm; nothing was sent"
                )

    def target(self, position_mm, angle_deg: float | None = None, what: str = "move") -> dict:
        """Checked machine coordinates for a head-frame position: head_to_axes + check_travel."""
        axes = self.head_to_axes(position_mm, angle_deg)
        self.check_travel(axes, what)
        return axes

    # ---------------------------------------------------------------- light

    def light_on_command(self) -> str:
        out = self.s.light.output
        if out == "coolant":
            return "M8"
        if out == "mist":
            return "M7"
        return f"M3 S{self.s.light.spindle_power:g}"

    def light_off_command(self) -> str:
        return "M5" if self.s.light.output == "spindle" else "M9"
