"""What a mesh_views plan needs of a capture folder before any photograph exists: the mesh (mesh.obj, .ply or
.glb, in scene.yaml's units) on its atlas at capture.texture_size, and the calibrated cameras: those images.json
names when the folder has one (cameras.json or a COLMAP model), else cameras.json. Cameras in mm, as the mesh."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from torchrefl.capture.cameras import Cameras
from torchrefl.capture.cameras_json import CAMERAS_JSON, read_cameras_json
from torchrefl.capture.colmap import read_colmap_model
from torchrefl.capture.images_json import IMAGES_JSON, read_images_json
from torchrefl.capture.mesh_views import mesh_path, read_units
from torchrefl.errors import CaptureError
from torchrefl.geometry.atlas_surface import AtlasGeometry, atlas_geometry
from torchrefl.geometry.mesh_file import UNIT_SCALE_MM, read_mesh


@dataclass(frozen=True)
class PlanInputs:
    """The folder's cameras (mm) and the mesh's atlas."""

    cameras: Cameras
    geometry: AtlasGeometry


def _cameras_path(folder: Path) -> Path:
    if (folder / IMAGES_JSON).is_file():
        return folder / read_images_json(folder / IMAGES_JSON).cameras
    path = folder / CAMERAS_JSON
    if not path.is_file():
        raise CaptureError(
            f"{folder}: no {CAMERAS_JSON} (and no {IMAGES_JSON} naming the cameras): a mesh_views plan needs the "
            "calibrated cameras beside the mesh"
        )
    return path


def read_plan_inputs(folder, texture_size: int, dtype=torch.float32) -> PlanInputs:
    """PlanInputs of a mesh_views folder (module doc); CaptureError / GeometryError naming the file at fault."""
    folder = Path(folder)
    units = read_units(folder)
    path = _cameras_path(folder)
    cameras = read_colmap_model(path) if path.is_dir() else read_cameras_json(path)
    geom = atlas_geometry(read_mesh(mesh_path(folder), units), texture_size, dtype=dtype)
    return PlanInputs(cameras.scaled(UNIT_SCALE_MM[units]), geom)
