"""The mesh a run's maps lie on, with UVs into the texel grid: what the OBJ and glTF exports write.

- cylindrical_scan: the range mesh (the grid triangulation the fit traced rays against, params.npz's
  `grid_faces`), one vertex per grid point (r, c) at the texel's position with the texel's normal and
  uv = ((c + 0.5) / W, 1 - (r + 0.5) / H). On a full turn the faces that join the last column to the first
  give the first column's corners u = 1 + 0.5 / W: the texture repeats (glTF's default sampler, Blender's
  default extension), so the seam samples the last and the first columns like any other pair.
- mesh_views: the capture's mesh with its atlas (params.npz's `mesh`; the grid is its texture).
- photometric_stereo: no mesh (None).
Positions in millimetres (the run's `units`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchrefl.errors import GeometryError, RunFolderError
from torchrefl.geometry.mesh_file import MeshData, read_mesh

TORCHREFL_MESH = "mesh.obj"  # the mesh torchrefl writes into a run folder when it made the atlas (report.outputs)


@dataclass(frozen=True)
class TexturedMesh:
    """vertices (V, 3) float64 in `units`; faces (F, 3) int64; uvs (F, 3, 2) the corners' texture coordinates (u
    right, v up: OBJ's convention; the texel grid's row 0 at v = 1); normals (V, 3) unit or None."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    normals: np.ndarray | None = None
    units: str = "mm"


def unique_rows(ids: np.ndarray, uvs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct (id, uv) pairs of corners: ids (N,) int (or None: uv alone), uvs (N, 2) in [0, 2]; returns
    (first (K,) the index of one corner of each distinct pair, inverse (N,) each corner's pair). UVs are told apart
    to 2^-24 (a 1-D sort of integer keys: np.unique over rows is several times slower on a scan's million
    corners)."""
    q = np.round(np.asarray(uvs, dtype=np.float64) * 2.0**24).astype(np.int64)
    _, uv_id = np.unique(q[:, 0] * 2**26 + q[:, 1], return_inverse=True)
    key = uv_id if ids is None else np.asarray(ids, dtype=np.int64) * (int(uv_id.max(initial=0)) + 1) + uv_id
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


def grid_uv(rows: np.ndarray, cols: np.ndarray, grid_shape: tuple[int, int]) -> np.ndarray:
    """(..., 2) uv of texel centres (rows, cols) on an (H, W) grid: ((c + 0.5) / W, 1 - (r + 0.5) / H)."""
    H, W = grid_shape
    return np.stack([(cols + 0.5) / W, 1.0 - (rows + 0.5) / H], -1)


def scan_mesh(positions: np.ndarray, normals: np.ndarray, grid_faces: np.ndarray, units: str = "mm") -> TexturedMesh:
    """The range mesh of a scan: positions, normals (H, W, 3) on the grid, grid_faces (F, 3) indices r * W + c.
    Only the grid points the faces use become vertices; wrap-around faces (spanning the first and the last
    column) get the first column's u shifted by 1."""
    H, W = positions.shape[:2]
    faces = np.asarray(grid_faces, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= H * W):
        raise GeometryError(f"grid_faces index grid points outside 0..{H * W - 1} of the {H} x {W} grid")
    used, compact = np.unique(faces, return_inverse=True)
    rows, cols = faces // W, faces % W
    uvs = grid_uv(rows, cols.astype(np.float64), (H, W))
    seam = (cols.max(axis=1) == W - 1) & (cols.min(axis=1) == 0) & (W > 2)
    uvs[seam, :, 0] += np.where(cols[seam] == 0, 1.0, 0.0)
    return TexturedMesh(
        vertices=positions.reshape(-1, 3)[used].astype(np.float64),
        faces=compact.reshape(-1, 3),
        uvs=uvs,
        normals=normals.reshape(-1, 3)[used].astype(np.float64),
        units=units,
    )


def atlas_mesh(mesh: MeshData) -> TexturedMesh:
    """A mesh_views mesh with its atlas (the texel grid is its texture)."""
    if mesh.uvs is None:
        raise GeometryError(f"mesh file {mesh.source}: has no UVs, expected the atlas the run's maps lie on")
    return TexturedMesh(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64), np.asarray(mesh.uvs))


def run_mesh_file(folder: Path, name: str) -> Path:
    """The file params.npz's `mesh` names: relative to the run folder or absolute."""
    path = Path(name)
    return path if path.is_absolute() else Path(folder) / path


def read_run_mesh(folder: Path, params: dict) -> TexturedMesh | None:
    """The mesh of a finished run from its params.npz arrays (`grid_faces` of a scan, `mesh` of mesh_views);
    None for a run without geometry (photometric stereo). RunFolderError naming the file when the mesh file the
    run names is gone."""
    if "grid_faces" in params:
        return scan_mesh(params["positions"], params["normals"], params["grid_faces"], str(params.get("units", "mm")))
    if "mesh" not in params:
        return None
    path = run_mesh_file(folder, str(params["mesh"]))
    if not path.is_file():
        raise RunFolderError(
            f"{Path(folder) / 'params.npz'}: key 'mesh' names {path}, which is missing (the mesh the maps lie on; "
            "expected the capture's mesh file where the run found it)"
        )
    from torchrefl.capture.mesh_views import read_units

    units = "mm" if path.resolve() == (Path(folder) / TORCHREFL_MESH).resolve() else read_units(path.parent)
    return atlas_mesh(read_mesh(path, units))
