"""The `selection` section of the config: candidate light positions (a grid in the scanner-head frame, world
positions for mesh_views) and the Ch. 2 stop rule."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from torchrefl.config_fields import opt


@dataclass
class LightGridConfig:
    """Candidate light positions on a 2-D grid in the scanner-head frame (co-rotating with the scan)."""

    columns: int = opt(10, "number of grid positions along the lateral axis", low=1)
    rows: int = opt(6, "number of grid positions along the vertical axis", low=1)
    spacing_mm: float = opt(50.0, "grid spacing in mm (the seed: 5 cm)", low=0.0)
    radial_mm: float = opt(300.0, "distance of the grid plane from the rotation axis, mm", low=0.0)
    center_lateral_mm: float = opt(0.0, "lateral offset of the grid centre from the camera, mm")
    center_vertical_mm: float = opt(0.0, "height of the grid centre, mm (world y)")


@dataclass
class WorldLightsConfig:
    """Candidate light positions in world coordinates for mesh_views plans (planning.world_candidates)."""

    layout: str = opt(
        "dome",
        "candidates: dome (rings of elevation x azimuth about the centre), gantry (selection.grid's nodes on the "
        "gantry plane) or file (the positions in `file`)",
        choices=("dome", "gantry", "file"),
    )
    file: str = opt("", "layout file: JSON/YAML list of [x, y, z] or {name: [x, y, z] | {position: ...}} positions, mm")
    centre_mm: Optional[list] = opt(None, "centre [x, y, z] of the dome, mm; null = the mesh's bounding-box centre")
    radius_mm: float = opt(350.0, "dome radius about the centre, mm", low=1.0)
    elevations_deg: list = opt([-30.0, 0.0, 30.0, 60.0], "dome ring elevations (towards +y), deg")
    azimuths: int = opt(12, "dome candidates per ring, evenly spaced in azimuth (from +z towards +x)", low=1)
    gantry_origin_mm: Optional[list] = opt(
        None, "world [x, y, z] of the gantry's lateral 0, vertical 0, mm; null = radius_mm along +z from the centre"
    )
    gantry_lateral: list = opt([1.0, 0.0, 0.0], "world unit vector of the gantry's lateral axis (unitless)")
    gantry_vertical: list = opt([0.0, 1.0, 0.0], "world unit vector of the gantry's vertical axis (unitless)")


@dataclass
class SelectionConfig:
    """Automatic light-position selection (dissertation Ch.2)."""

    enabled: bool = opt(True, "select lights among the candidates (synthetic captures render only those)")
    grid: LightGridConfig = field(
        default_factory=LightGridConfig,
        metadata={"doc": "candidate light grid (mesh_views: the gantry layout's nodes, lateral x vertical)"},
    )
    world: WorldLightsConfig = field(
        default_factory=WorldLightsConfig,
        metadata={"doc": "mesh_views: candidate light positions in world coordinates"},
    )
    stop_ratio: float = opt(
        0.8, "th1: stop when specular coverage reaches this fraction of the all-candidates coverage", low=0.0, high=1.0
    )
    max_lights: int = opt(20, "never select more lights than this", low=1)
    num_lights: Optional[int] = opt(None, "select exactly this many lights (overrides the stop rule)")
