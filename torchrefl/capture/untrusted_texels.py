"""The texels of a cylindrical scan whose geometry cannot be trusted: silhouettes, creases, mixed footprints and
texels no range-fitting window describes (torchrefl.geometry.footprint, range_mesh); the loader leaves their
observations out and reports them as coverage code 4. Also the observations whose footprint a cast shadow's edge
may cross (shadow_edge_observations), which the loader leaves out as well."""

from __future__ import annotations

import numpy as np
import torch

from torchrefl.capture.cylindrical_rig import CylindricalRig
from torchrefl.core.texel_neighbours import TexelNeighbours
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


#: grid neighbours whose unit normals' cosine is below this lie across a crease: a shadow edge there is the crease's
SAME_FACE_COS = 0.9


def shadow_edge_observations(shadowed: np.ndarray, neighbours: TexelNeighbours, normals: np.ndarray) -> np.ndarray:
    """(P, T) bool: lit observations (not in cast shadow) of texels with a surface neighbour (4-neighbourhood of
    neighbours, the Surface's: on a scan of the full turn the first and last columns are neighbours, on an atlas
    the texel across a seam is one) on the same face (normals within SAME_FACE_COS) that is in cast shadow. The
    texel's colour integrates a footprint reaching half-way to its neighbours, so the shadow's edge may cross it,
    while the model shades the texel's centre only: such an observation reads anything between lit and dark (on
    the fold at full size they were 0.4 % of the fitted observations and 47 % of the squared image residual at
    the true parameters)."""
    shadowed = np.asarray(shadowed, dtype=bool)
    n = np.asarray(normals, dtype=np.float64)
    edge = np.zeros_like(shadowed)
    t = np.arange(neighbours.num_texels)
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        other = neighbours.neighbour(t, dy, dx)
        same = np.flatnonzero((other >= 0) & (np.einsum("ti,ti->t", n, n[np.maximum(other, 0)]) >= SAME_FACE_COS))
        edge[:, same] |= shadowed[:, other[same]]
    return edge & ~shadowed


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
