"""Mesh objects for synthetic cylindrical scans, with exact normals and materials defined on the object.

Each object is a MeshObject: the triangle mesh Embree traces (fine where the object is curved,
exact where it is flat), `normal(points, triangles)` giving the exact surface normal and
`material(points, triangles)` giving the true reflectance at any surface point (path vertices of
the interreflection renderer need it away from texel centres).

The cylindrical scanner looks horizontally at the rotation axis (world y up); a point is scanned
from the side of the axis it lies on, so the faces that must be seen (the inside of the fold, the
inside of the bowl) are placed in front of the axis, facing outwards, towards scan angle s = pi
(world +z) turned by the object's yaw.

- object_e: the seed's Object E (Fig. 3.12-3.13): two plates 120 mm (along the fold) x 80 mm x 3 mm
  joined at a 90 degree fold. The fold is horizontal (the seed plots the Pd profile along the
  object's vertical direction), 15 mm in front of the axis; the opening's bisector is tilted 15
  degrees upwards and the whole object turned 20 degrees about the vertical axis, so the upper
  plate (region 0, Region I) faces 30 degrees downwards and the lower plate (region 1, Region II)
  60 degrees upwards: both insides are seen over a wide range of scan angles. Setup 1: white
  diffuse paper everywhere; setup 2 (object_e_glossy): glossy paper everywhere.
- fold: Object E's geometry covered with non-uniform glossy papers (synthetic.materials.FoldMaterials:
  two papers per plate with a sharp border, a band of a fifth, smooth variation; Ps 0.23-0.5, sigma
  0.085-0.35), the hard case of Method III: specular interreflection between regions of different lobes.
- bowl: a hemispherical shell (inner radius 45 mm, 4 mm wall) lying on its side with its opening
  towards the scanner (tilted 10 degrees upwards, turned 20 degrees about the vertical), its centre
  62 mm in front of the axis, so the scanner looks into it; the inside carries non-uniform
  materials (synthetic.materials.BowlMaterials), the outside and the rim a uniform matte paint.
  A cylindrical scanner sees only about a third of that inside (its lines of sight converge on the
  axis), so most of the surface that lights the scanned part is missing from the scan.
- vase: a solid of revolution about the rotation axis (a vase shape: a cylindrical body, a deep
  concave neck whose profile is a circular arc, rounded shoulders, flat ends). Every point of a
  surface of revolution about the axis faces outwards along the scanner's line of sight, so the
  scan captures all of the concave neck and every surface that lights it: the fitter sees the whole
  interreflecting geometry. Its materials are texel-aligned region maps of the scan grid
  (synthetic.materials.region_materials, as the analytic ellipsoid's), given by the scanner
  (material None here): every texel has one true value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh

from torchrefl.errors import GeometryError
from torchrefl.synthetic.materials import PAPER_GLOSSY, PAPER_WHITE, BowlMaterials, FoldMaterials, uniform_material

MESH_OBJECTS = ("object_e", "object_e_glossy", "fold", "bowl", "vase")


@dataclass
class MeshObject:
    """vertices (V, 3) float64 mm, faces (F, 3) int; normal(points (N,3), triangles (N,)) -> (N, 3) unit
    outward normals; material(points, triangles) -> {'pd': (N,3), 'ps': (N,3), 'sigma': (N,), 'region': (N,)},
    or None for objects whose materials are texel maps of the scan grid (the scanner supplies them);
    extent_y: (min, max) world height; info: the object's defining geometry in world coordinates (Object E:
    fold_start (3,), fold_dir (3,) unit along the fold, plate_dirs (2, 3) unit directions of the plates from
    the fold (upper, lower), inside_normals (2, 3), length, width; bowl: centre, axis, radius, wall, inner_faces
    (faces of the inside: 0..inner_faces-1); vase: profile (VaseProfile), core, groove_radius, y_edge, r_max,
    half_height, side_faces (faces of the side: 0..side_faces-1))."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normal: Callable[[np.ndarray, np.ndarray], np.ndarray]
    material: Callable[[np.ndarray, np.ndarray], dict] | None
    extent_y: tuple
    info: dict


def _rot_x(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


def _rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def _box(origin, e1, e2, e3, lengths) -> trimesh.Trimesh:
    """Box spanned from `origin` by lengths along orthonormal axes e1, e2, e3 (outward faces)."""
    R = np.stack([e1, e2, e3], 1)
    m = trimesh.creation.box(extents=lengths)
    m.apply_translation(np.asarray(lengths) / 2.0)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = origin
    m.apply_transform(T)
    if np.linalg.det(R) < 0:
        m.invert()
    return m


def object_e(
    glossy: bool = False,
    *,
    papers: FoldMaterials | None = None,
    length: float = 120.0,
    width: float = 80.0,
    thickness: float = 3.0,
    fold_front: float = 15.0,
    tilt_deg: float = 15.0,
    yaw_deg: float = 20.0,
) -> MeshObject:
    """Object E: two plates at 90 degrees (see the module doc); regions 0 (upper plate) and 1 (lower)."""
    bis_elev = np.radians(tilt_deg)
    dA = np.array([0.0, np.sin(bis_elev + np.pi / 4), np.cos(bis_elev + np.pi / 4)])  # upper plate, from the fold
    dB = np.array([0.0, np.sin(bis_elev - np.pi / 4), np.cos(bis_elev - np.pi / 4)])  # lower plate
    ex = np.array([1.0, 0.0, 0.0])
    y_top = width * dA[1]
    y_bot = width * dB[1]
    fold = np.array([-length / 2.0, -(y_top + y_bot) / 2.0, fold_front])
    # plate A: a in [-T, W] along dA, b in [-T, 0] along dB (its inside face b = 0 has normal +dB);
    # plate B: a in [-T, 0], b in [0, W] (inside face a = 0, normal +dA). Frames (dA, dB, ex) are
    # right-handed or not depending on the tilt; _box fixes the winding.
    A = _box(fold - thickness * dA - thickness * dB, dA, dB, ex, (width + thickness, thickness, length))
    B = _box(fold - thickness * dA, dA, dB, ex, (thickness, width, length))
    R = _rot_y(yaw_deg)
    verts = np.concatenate([A.vertices, B.vertices]) @ R.T
    faces = np.concatenate([A.faces, B.faces + len(A.vertices)])
    mesh = trimesh.Trimesh(verts, faces, process=False)
    fn = np.asarray(mesh.face_normals, dtype=np.float64)
    nA = len(A.faces)
    mat = PAPER_GLOSSY if glossy else PAPER_WHITE

    def normal(points, tri):
        return fn[tri]

    def material(points, tri):
        plate = (np.asarray(tri) >= nA).astype(np.int64)
        if papers is None:
            return uniform_material(len(tri), mat, region=plate)
        local = (np.asarray(points) @ R) - fold  # plate frame: along the fold (ex), across each plate (dA, dB)
        across = np.where(plate == 0, local @ dA, local @ dB) / width
        return papers(local @ ex / length, across, plate)

    info = {
        "fold_start": R @ fold,
        "fold_dir": R @ ex,
        "plate_dirs": np.stack([R @ dA, R @ dB]),
        "inside_normals": np.stack([R @ dB, R @ dA]),
        "length": length,
        "width": width,
        "thickness": thickness,
    }
    return MeshObject(
        "fold" if papers is not None else "object_e_glossy" if glossy else "object_e",
        verts,
        faces,
        normal,
        material,
        (float(verts[:, 1].min()), float(verts[:, 1].max())),
        info,
    )


def _grid_faces(rows: int, cols: int, start: int, flip: bool) -> np.ndarray:
    """Two triangles per cell of a (rows+1) x cols vertex grid, periodic in columns."""
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    a = start + i * cols + j
    b = start + i * cols + (j + 1) % cols
    c = a + cols
    d = b + cols
    f = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return f[:, ::-1] if flip else f


def bowl(
    seed: int = 0,
    uniform: bool = False,
    *,
    radius: float = 45.0,
    wall: float = 4.0,
    centre_front: float = 62.0,
    tilt_deg: float = 10.0,
    yaw_deg: float = 20.0,
    rings: int = 96,
    segments: int = 384,
) -> MeshObject:
    """A hemispherical bowl on its side, looked into by the scanner (see the module doc)."""
    R = _rot_y(yaw_deg) @ _rot_x(-tilt_deg)
    centre = R @ np.array([0.0, 0.0, centre_front])
    axis = R @ np.array([0.0, 0.0, 1.0])  # opening direction
    e1 = R @ np.array([1.0, 0.0, 0.0])
    e2 = R @ np.array([0.0, 1.0, 0.0])
    alpha = np.linspace(0.0, np.pi / 2, rings + 1)
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    A, P = np.meshgrid(alpha, phi, indexing="ij")
    unit = (
        np.sin(A)[..., None] * (np.cos(P)[..., None] * e1 + np.sin(P)[..., None] * e2) - np.cos(A)[..., None] * axis
    ).reshape(-1, 3)
    inner = centre + radius * unit
    outer = centre + (radius + wall) * unit
    nv = len(inner)
    f_in = _grid_faces(rings, segments, 0, flip=False)
    f_out = _grid_faces(rings, segments, nv, flip=True)
    rim_inner = rings * segments + np.arange(segments)
    rim_outer = nv + rim_inner
    nxt = np.roll(np.arange(segments), -1)
    f_rim = np.concatenate(
        [
            np.stack([rim_inner, rim_outer, rim_outer[nxt]], -1),
            np.stack([rim_inner, rim_outer[nxt], rim_inner[nxt]], -1),
        ]
    )
    verts = np.concatenate([inner, outer])
    faces = np.concatenate([f_in, f_out, f_rim])
    n_in, n_out = len(f_in), len(f_out)
    mats = BowlMaterials(seed, uniform)

    def part_of(tri):
        tri = np.asarray(tri)
        return np.where(tri < n_in, 0, np.where(tri < n_in + n_out, 1, 2))

    def normal(points, tri):
        part = part_of(tri)
        d = points - centre
        d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
        n = np.where((part == 0)[:, None], -d, d)
        return np.where((part == 2)[:, None], axis[None, :], n)

    def material(points, tri):
        d = points - centre
        h = -d @ axis
        a = np.arctan2(np.linalg.norm(d - np.outer(d @ axis, axis), axis=-1), h)
        ph = np.arctan2(d @ e2, d @ e1)
        return mats(np.clip(a, 0.0, np.pi / 2), ph, part_of(tri))

    info = {"centre": centre, "axis": axis, "radius": radius, "wall": wall, "inner_faces": n_in}
    return MeshObject(
        "bowl", verts, faces, normal, material, (float(verts[:, 1].min()), float(verts[:, 1].max())), info
    )


class VaseProfile:
    """The vase's profile r(y) (mm from the axis at height y) and its slope dr/dy, symmetric about y = 0.

    |y| <= y_edge: the neck, a circular arc of radius `groove_radius` bulging towards the axis (its
    centre at radius core + groove_radius, height 0), core radius at y = 0, slopes +-tan(flank_deg) at
    its edges; then a convex arc of radius `shoulder_radius`, tangent to the neck, up to the vertical;
    then a cylinder up to |y| = half_height. C1 everywhere; analytic."""

    def __init__(self, core: float, groove_radius: float, flank_deg: float, shoulder_radius: float, half_height: float):
        self.core, self.rho, self.rho2, self.half_height = core, groove_radius, shoulder_radius, half_height
        a = np.radians(flank_deg)
        self.rc = core + groove_radius  # neck arc centre radius
        self.y_edge = groove_radius * np.sin(a)
        self.r_edge = self.rc - groove_radius * np.cos(a)
        # convex shoulder: centre inside the solid, tangent at the neck's edge; its normal turns from
        # (cos a, -sin a) (the neck arc's at the edge, in (r, y)) to (1, 0)
        self.c2 = (self.r_edge - shoulder_radius * np.cos(a), self.y_edge + shoulder_radius * np.sin(a))
        self.r_max = self.c2[0] + shoulder_radius
        if self.c2[1] >= half_height:
            raise GeometryError("vase: the shoulders do not fit in the half height")

    def radius(self, y: np.ndarray) -> np.ndarray:
        ay = np.abs(y)
        neck = self.rc - np.sqrt(np.maximum(self.rho**2 - ay**2, 0.0))
        sh = self.c2[0] + np.sqrt(np.maximum(self.rho2**2 - (ay - self.c2[1]) ** 2, 0.0))
        return np.where(ay <= self.y_edge, neck, np.where(ay <= self.c2[1], sh, self.r_max))

    def slope(self, y: np.ndarray) -> np.ndarray:
        """dr/dy."""
        ay = np.abs(y)
        neck = ay / np.sqrt(np.maximum(self.rho**2 - ay**2, 1e-12))
        dy = ay - self.c2[1]
        sh = -dy / np.sqrt(np.maximum(self.rho2**2 - dy**2, 1e-12))
        return np.sign(y) * np.where(ay <= self.y_edge, neck, np.where(ay <= self.c2[1], sh, 0.0))


def vase(
    *,
    core: float = 45.0,
    groove_radius: float = 40.0,
    flank_deg: float = 60.0,
    shoulder_radius: float = 20.0,
    half_height: float = 56.0,
    step_mm: float = 0.25,
    segments: int = 1440,
) -> MeshObject:
    """The vase (see the module doc): a solid of revolution about the world y axis with a concave neck.
    Parts: side (region of the texel maps), flat top and bottom ends. Normals are the exact surface's."""
    prof = VaseProfile(core, groove_radius, flank_deg, shoulder_radius, half_height)
    ys = np.linspace(-half_height, half_height, int(round(2 * half_height / step_mm)) + 1)
    rs = prof.radius(ys)
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    side = np.stack(
        [
            rs[:, None] * np.sin(phi)[None, :],
            np.broadcast_to(ys[:, None], (len(ys), segments)),
            rs[:, None] * np.cos(phi)[None, :],
        ],
        -1,
    ).reshape(-1, 3)
    f_side = _grid_faces(len(ys) - 1, segments, 0, flip=False)
    nv = len(side)
    centres = np.array([[0.0, -half_height, 0.0], [0.0, half_height, 0.0]])
    ring_lo = np.arange(segments)
    ring_hi = (len(ys) - 1) * segments + np.arange(segments)
    nxt = np.roll(np.arange(segments), -1)
    f_bottom = np.stack([np.full(segments, nv), ring_lo[nxt], ring_lo], -1)
    f_top = np.stack([np.full(segments, nv + 1), ring_hi, ring_hi[nxt]], -1)
    verts = np.concatenate([side, centres])
    faces = np.concatenate([f_side, f_bottom, f_top])
    n_side = len(f_side)

    def normal(points, tri):
        tri = np.asarray(tri)
        y = points[:, 1]
        r = np.maximum(np.hypot(points[:, 0], points[:, 2]), 1e-12)
        n = np.stack([points[:, 0] / r, -prof.slope(y), points[:, 2] / r], -1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        ends = np.stack([np.zeros_like(y), np.sign(y), np.zeros_like(y)], -1)
        return np.where((tri >= n_side)[:, None], ends, n)

    info = {
        "profile": prof,
        "core": core,
        "groove_radius": groove_radius,
        "y_edge": float(prof.y_edge),
        "r_max": float(prof.r_max),
        "half_height": half_height,
        "side_faces": n_side,
    }
    return MeshObject("vase", verts, faces, normal, None, (-half_height, half_height), info)


def make_object(name: str, seed: int = 0, materials: str = "regions") -> MeshObject:
    """The mesh object `name` (one of MESH_OBJECTS); materials 'uniform' makes the bowl one matte paint."""
    if name == "object_e":
        return object_e(glossy=False)
    if name == "object_e_glossy":
        return object_e(glossy=True)
    if name == "fold":
        return object_e(glossy=True, papers=FoldMaterials(seed))
    if name == "bowl":
        return bowl(seed, uniform=materials == "uniform")
    if name == "vase":
        return vase()
    raise GeometryError(f"synthetic.object: unknown mesh object '{name}', expected one of {', '.join(MESH_OBJECTS)}")
