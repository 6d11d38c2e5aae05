"""Reading and writing the triangle mesh of a `mesh_views` capture (mesh.obj, mesh.ply or mesh.glb).

The mesh is one triangle mesh in millimetres: a glb scene with several meshes is concatenated with its node
transforms applied, and positions in another unit (`units`: mm, cm, m, in) are scaled to millimetres. UVs are
kept per face corner (uvs (F, 3, 2)), as the file gives them: trimesh splits vertices at UV seams when it loads
an OBJ without `maintain_order` (with `maintain_order=True` it keeps one UV per position and loses the seams),
so vertex v of the loaded mesh carries one UV and uvs = uv[faces].
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from torchrefl.errors import GeometryError

# Millimetres per unit of the mesh file (the `units` argument, scene.yaml's `units`).
UNIT_SCALE_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
MESH_SUFFIXES = (".obj", ".ply", ".glb")
# UVs may leave [0, 1] by this much (float rounding in exporters) and are clipped to it.
UV_TOLERANCE = 1e-4


@dataclass
class MeshData:
    """A triangle mesh in millimetres.

    vertices: (V, 3) float64, mm. faces: (F, 3) int64. uvs: (F, 3, 2) float64 texture coordinates of each face
    corner (u right, v up, both in [0, 1]), None when the file has none. source: the file it came from."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: Optional[np.ndarray] = None
    source: str = "<memory>"

    @property
    def has_uvs(self) -> bool:
        return self.uvs is not None

    def face_areas(self) -> np.ndarray:
        """(F,) 3-D area of each face, mm^2."""
        v = self.vertices[self.faces]
        return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


def _load_trimesh(path: Path):
    import trimesh

    try:
        loaded = trimesh.load(str(path), process=False, force="mesh")
    except Exception as exc:  # trimesh raises many types on a damaged file
        raise GeometryError(f"mesh file {path}: cannot be read as a triangle mesh ({exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh):
        raise GeometryError(f"mesh file {path}: expected a triangle mesh, got {type(loaded).__name__}")
    return loaded


def _corner_uvs(mesh, path: Path) -> Optional[np.ndarray]:
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) == 0:
        return None
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape != (len(mesh.vertices), 2):
        raise GeometryError(
            f"mesh file {path}: {uv.shape[0]} UVs for {len(mesh.vertices)} vertices (expected one each)"
        )
    return uv[np.asarray(mesh.faces, dtype=np.int64)]


def check_mesh(mesh: MeshData) -> None:
    """Raise GeometryError naming mesh.source when the mesh cannot carry an atlas: no faces, NaN / inf vertices,
    faces indexing missing vertices, every face degenerate, UVs NaN or outside [0, 1] beyond UV_TOLERANCE."""
    where = f"mesh file {mesh.source}"
    if len(mesh.faces) == 0:
        raise GeometryError(f"{where}: the mesh has no faces (expected a triangle mesh with at least one face)")
    bad = ~np.isfinite(mesh.vertices).all(axis=1)
    if bad.any():
        raise GeometryError(f"{where}: {int(bad.sum())} of {len(bad)} vertices have NaN or inf coordinates")
    if mesh.faces.min() < 0 or mesh.faces.max() >= len(mesh.vertices):
        raise GeometryError(f"{where}: faces index vertices outside 0..{len(mesh.vertices) - 1}")
    scale = float(np.ptp(mesh.vertices, axis=0).max())
    if not (mesh.face_areas() > 1e-12 * max(scale, 1e-300) ** 2).any():
        raise GeometryError(f"{where}: all {len(mesh.faces)} faces are degenerate (zero area)")
    if mesh.uvs is not None:
        finite = np.isfinite(mesh.uvs).all(axis=(1, 2))
        outside = finite & ((mesh.uvs < -UV_TOLERANCE) | (mesh.uvs > 1 + UV_TOLERANCE)).any(axis=(1, 2))
        if (~finite).any() or outside.any():
            lo, hi = np.nanmin(mesh.uvs), np.nanmax(mesh.uvs)
            raise GeometryError(
                f"{where}: UVs must lie in [0, 1] (one texture atlas); {int(outside.sum())} faces have UVs outside "
                f"it (range {lo:.4g}..{hi:.4g}) and {int((~finite).sum())} NaN or inf: a tiled or wrapped UV "
                "layout cannot hold one reflectance per texel"
            )


def read_mesh(path, units: str = "mm") -> MeshData:
    """The mesh in `path` (.obj, .ply or .glb) as a checked MeshData in millimetres; `units` is the file's length
    unit (mm, cm, m, in). Raises GeometryError naming the file on an unknown suffix or unit, an unreadable file
    or a mesh check_mesh refuses."""
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise GeometryError(f"mesh file {path}: expected one of {', '.join(MESH_SUFFIXES)}, got '{path.suffix}'")
    if units not in UNIT_SCALE_MM:
        raise GeometryError(f"mesh file {path}: unknown units {units!r}, expected one of {', '.join(UNIT_SCALE_MM)}")
    if not path.is_file():
        raise GeometryError(f"mesh file {path}: not found")
    tm = _load_trimesh(path)
    mesh = MeshData(
        vertices=np.asarray(tm.vertices, dtype=np.float64) * UNIT_SCALE_MM[units],
        faces=np.asarray(tm.faces, dtype=np.int64).reshape(-1, 3),
        uvs=_corner_uvs(tm, path) if len(tm.faces) else None,
        source=str(path),
    )
    check_mesh(mesh)
    if mesh.uvs is not None:
        mesh.uvs = np.clip(mesh.uvs, 0.0, 1.0)
    return mesh


def write_obj(path, mesh: MeshData) -> None:
    """Write mesh as a Wavefront OBJ (v in mm, one vt per face corner when it has UVs, f v/vt), which read_mesh
    reads back to the same corner positions and UVs (trimesh splits a vertex that has several UVs)."""
    path = Path(path)
    lines = ["# torchrefl mesh, millimetres"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in mesh.vertices]
    faces = np.asarray(mesh.faces, dtype=np.int64) + 1
    if mesh.uvs is None:
        lines += [f"f {a} {b} {c}" for a, b, c in faces]
    else:
        uv, corner = np.unique(mesh.uvs.reshape(-1, 2), axis=0, return_inverse=True)
        lines += [f"vt {u:.9g} {v:.9g}" for u, v in uv]
        t = corner.reshape(-1, 3) + 1
        lines += [f"f {a}/{ta} {b}/{tb} {c}/{tc}" for (a, b, c), (ta, tb, tc) in zip(faces, t)]
    path.write_text("\n".join(lines) + "\n")
