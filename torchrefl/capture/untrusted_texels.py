"""The texels of a cylindrical scan whose geometry cannot be trusted: silhouettes, creases, mixed footprints and
texels no range-fitting window describes (torchrefl.geometry.footprint, range_mesh); the loader leaves their
observations out and reports them as coverage code 4. (The observations whose footprint a cast shadow's edge may
cross: capture.shadow_edges.)"""

from __future__ import annotations

import numpy as np
import torch

from torchrefl.capture.cylindrical_rig import CylindricalRig
from torchrefl.geometry.cylindrical import cylindrical_points
from torchrefl.geometry.footprint import mixed_footprints
from torchrefl.geometry.range_image import RangeGeometry
from torchrefl.geometry.range_mesh import boundary_texels, crease_texels


def mixed_footprint_grid(r: np.ndarray, valid: np.ndarray, geo: RangeGeometry, rig: CylindricalRig) -> np.ndarray:
    """(H, W) bool: texels of the preprocessed range image geo whose footprint the scanned range r (H, W) mm
    (valid (H, W)) shows to be mixed (torchrefl.geometry.footprint), the range noise estimated from r itself."""
    H, W = r.shape
    s = torch.from_numpy(rig.angle0 + rig.angle_step * np.arange(W))
    t = torch.from_numpy(rig.height0 + rig.height_step * np.arange(H))
    measured = cylindrical_points(torch.from_numpy(np.where(valid, r, np.nan)), s, t).numpy()
    ok = geo.valid.numpy() & valid
    return mixed_footprints(
        measured,
        geo.points.double().numpy(),
        geo.normals.double().numpy(),
        ok,
        noise_mm=geo.noise_mm,
        wrap=rig.covers_full_turn(),
    )


def untrusted_geometry(geom, edge_width: int, crease_angle_deg) -> dict:
    """Texels of a ScanGeometry whose geometry cannot be trusted, {reason: (T,) bool}: 'edge' within edge_width
    texels of the mesh boundary (range_mesh.boundary_texels), 'crease' on a crease sharper than crease_angle_deg
    (range_mesh.crease_texels; None: none), 'mixed' a mixed footprint (geom.mixed, geometry.footprint), 'unfit' no
    range-fitting window describes it (geom.unfit)."""
    H, W = geom.surface.grid_shape
    idx = geom.surface.texel_index.numpy()
    edge = boundary_texels(geom.surface.mesh_faces, (H, W), idx, edge_width)
    crease = crease_texels(
        geom.surface.mesh_vertices,
        geom.surface.mesh_faces,
        geom.surface.normals.double().numpy(),
        idx,
        crease_angle_deg,
    )
    none = np.zeros(idx.size, dtype=bool)
    mixed = none if geom.mixed is None else np.asarray(geom.mixed, dtype=bool)
    unfit = none if geom.unfit is None else np.asarray(geom.unfit, dtype=bool)
    return {"edge": edge, "crease": crease, "mixed": mixed, "unfit": unfit}


def untrusted_counts(texels: dict) -> dict:
    """The loader statistics of untrusted_geometry's masks: each kind counts the texels the kinds before it did not."""
    edge, crease, mixed = texels["edge"], texels["crease"], texels["mixed"]
    return {
        "edge_texels_excluded": int(edge.sum()),
        "crease_texels_excluded": int((crease & ~edge).sum()),
        "mixed_footprint_texels_excluded": int((mixed & ~edge & ~crease).sum()),
        "unfit_range_texels_excluded": int((texels["unfit"] & ~mixed & ~edge & ~crease).sum()),
    }
