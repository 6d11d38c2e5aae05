"""Candidate light positions in world coordinates (mesh_views plans), from the config's selection.world:

- dome: one ring per elevation e (towards +y) of `azimuths` positions at azimuth a (from +z towards +x, ring r
  turned by r / rings of the spacing), at radius_mm about the centre: centre + radius (cos e sin a, sin e,
  cos e cos a), the convention of the synthetic scenes' cameras and lights;
- gantry: the nodes of selection.grid (columns x rows at spacing_mm, centred on center_lateral_mm,
  center_vertical_mm; the rig's grid layout) on the gantry plane: origin + lateral * u + vertical * v, with u, v
  the world directions of the gantry's axes. Each candidate keeps its gantry coordinates [lateral, vertical] (mm),
  which the rig moves to;
- file: the positions listed in a JSON/YAML file (mm): a list of [x, y, z], or a mapping of names to [x, y, z]
  or to {position: [x, y, z], ...} (lights.json's form).

The centre is centre_mm, or the centre of the mesh's bounding box.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import yaml

from torchrefl.capture.cylindrical_rig import light_grid_positions
from torchrefl.config import LightGridConfig, WorldLightsConfig
from torchrefl.errors import ConfigError


@dataclass(frozen=True)
class GantryFrame:
    """Where the gantry's plane lies in the world: origin_mm (3,) the world point at lateral 0, vertical 0;
    lateral, vertical (3,) world unit vectors of its axes."""

    origin_mm: np.ndarray
    lateral: np.ndarray
    vertical: np.ndarray

    def world(self, gantry_mm) -> np.ndarray:
        """(..., 3) world positions of gantry coordinates (..., 2) [lateral, vertical] mm."""
        g = np.asarray(gantry_mm, dtype=np.float64)
        return self.origin_mm + g[..., :1] * self.lateral + g[..., 1:2] * self.vertical

    def to_json(self) -> dict:
        return {
            "origin_mm": [float(x) for x in self.origin_mm],
            "lateral": [float(x) for x in self.lateral],
            "vertical": [float(x) for x in self.vertical],
        }


@dataclass(frozen=True)
class WorldCandidates:
    """P candidate lights: names, positions (P, 3) world mm; for the gantry layout its frame and each
    candidate's gantry coordinates gantry_mm (P, 2) [lateral, vertical] (None for the other layouts)."""

    layout: str
    names: tuple[str, ...]
    positions: np.ndarray
    frame: Optional[GantryFrame] = None
    gantry_mm: Optional[np.ndarray] = None

    def __len__(self) -> int:
        return len(self.names)


def _vector(value, key: str, unit: bool = False) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64) if isinstance(value, (list, tuple)) else None
    if v is None or v.shape != (3,) or not np.isfinite(v).all():
        raise ConfigError(f"selection.world.{key} is {value!r}, expected 3 finite numbers [x, y, z]")
    if unit:
        norm = float(np.linalg.norm(v))
        if norm == 0:
            raise ConfigError(f"selection.world.{key} is {value!r}, expected a non-zero direction")
        v = v / norm
    return v


def dome_positions(centre, radius: float, elevations_deg, azimuths: int) -> np.ndarray:
    """(rings * azimuths, 3) the dome's positions, ring by ring (module doc)."""
    rings = len(elevations_deg)
    e = np.radians(np.asarray(elevations_deg, dtype=np.float64))[:, None]
    a = np.radians(360.0 * (np.arange(azimuths)[None, :] + np.arange(rings)[:, None] / rings) / azimuths)
    d = np.stack(np.broadcast_arrays(np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)), -1)
    return np.asarray(centre, dtype=np.float64) + radius * d.reshape(-1, 3)


def gantry_frame(world: WorldLightsConfig, centre) -> GantryFrame:
    """The gantry plane of selection.world; ConfigError when its axes are not perpendicular."""
    u = _vector(world.gantry_lateral, "gantry_lateral", unit=True)
    v = _vector(world.gantry_vertical, "gantry_vertical", unit=True)
    if abs(float(u @ v)) > 1e-6:
        raise ConfigError(
            f"selection.world.gantry_lateral {world.gantry_lateral} and gantry_vertical {world.gantry_vertical} "
            "are not perpendicular: expected the gantry's two axes at right angles"
        )
    origin = (
        _vector(world.gantry_origin_mm, "gantry_origin_mm")
        if world.gantry_origin_mm is not None
        else np.asarray(centre, dtype=np.float64) + np.array([0.0, 0.0, world.radius_mm])
    )
    return GantryFrame(origin, u, v)


def _listed(doc, path: Path) -> tuple[list[str], np.ndarray]:
    if isinstance(doc, dict):
        names = [str(k) for k in doc]
        values = [v.get("position") if isinstance(v, dict) else v for v in doc.values()]
    elif isinstance(doc, list):
        names = [f"L{k:03d}" for k in range(len(doc))]
        values = doc
    else:
        raise ConfigError(f"{path}: expected a list of [x, y, z] positions or a mapping of names to positions (mm)")
    out = []
    for name, value in zip(names, values):
        ok = isinstance(value, list) and len(value) == 3 and all(isinstance(x, (int, float)) for x in value)
        if not ok or not np.isfinite(np.asarray(value, dtype=np.float64)).all():
            raise ConfigError(f"{path}: light {name!r} has position {value!r}, expected 3 finite numbers (mm)")
        out.append(value)
    if not out:
        raise ConfigError(f"{path}: lists no light positions")
    return names, np.asarray(out, dtype=np.float64)


def read_positions_file(path) -> tuple[list[str], np.ndarray]:
    """(names, positions (P, 3) mm) of a candidate file (module doc); ConfigError naming the file otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: candidate light file (selection.world.file) not found")
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))  # YAML reads JSON too
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid JSON/YAML ({exc})") from None
    return _listed(doc, path)


def world_candidates(
    world: WorldLightsConfig, grid: LightGridConfig, mesh_vertices: np.ndarray, config_dir: str | Path = "."
) -> WorldCandidates:
    """The candidates of selection.world (module doc) about the mesh (vertices (V, 3) mm); a relative `file` is
    relative to config_dir."""
    v = np.asarray(mesh_vertices, dtype=np.float64)
    centre = _vector(world.centre_mm, "centre_mm") if world.centre_mm is not None else (v.min(0) + v.max(0)) / 2
    if world.layout == "dome":
        if not world.elevations_deg:
            raise ConfigError("selection.world.elevations_deg is empty, expected one elevation (deg) per dome ring")
        pos = dome_positions(centre, world.radius_mm, world.elevations_deg, world.azimuths)
        return WorldCandidates("dome", tuple(f"L{k:03d}" for k in range(len(pos))), pos)
    if world.layout == "gantry":
        frame = gantry_frame(world, centre)
        g = light_grid_positions(
            grid.columns, grid.rows, grid.spacing_mm, 0.0, grid.center_lateral_mm, grid.center_vertical_mm
        )[:, :2]
        names = tuple(f"L{k:03d}" for k in range(len(g)))
        return WorldCandidates("gantry", names, frame.world(g), frame, g)
    if not world.file:
        raise ConfigError("selection.world.layout is 'file' but selection.world.file is empty: name the file")
    path = Path(world.file)
    names, pos = read_positions_file(path if path.is_absolute() else Path(config_dir) / path)
    return WorldCandidates("file", tuple(names), pos)
