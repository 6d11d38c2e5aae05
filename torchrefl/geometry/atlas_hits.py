"""The atlas's TexelHits (core/texel_hits.py): which texel a point of the real mesh belongs to, by its uv.

The interreflection levels trace the mesh itself. A point of face f at barycentric weights b has the uv
sum_k b_k uv_fk; in texel coordinates (x, y) = (u S, (1 - v) S) (geometry/atlas.py) it lies in grid cell
(row, col) = (floor y, floor x), the texel whose centre is ((col + 0.5) / S, 1 - (row + 0.5) / S). A cell that holds
no texel of f's chart (the gutter, a cell whose centre lies outside every triangle, or one taken by a chart packed
beside it) goes to the nearest texel of f's chart on the grid (a per-chart lookup over the chart's bounding box of
cells, scipy.ndimage.distance_transform_edt); a chart with no texel at all (degenerate UVs) goes to the texel nearest
its faces' centroid in 3-D. Every point thus maps to a texel of its own chart, and each texel collects photons over
its own area (Surface.areas: the texel's UV area times its face's 3-D / UV area ratio). Face normals are turned to
the side the normal of the texel at the face's UV centroid faces. No fold rule: the real triangles are the surface,
so a ray sees the texel it meets.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from torchrefl.errors import GeometryError
from torchrefl.geometry.atlas import AtlasTexels, uv_to_texel_xy
from torchrefl.geometry.atlas_charts import face_charts
from torchrefl.geometry.mesh_file import MeshData
from torchrefl.geometry.range_mesh import oriented_face_normals


@dataclass
class ChartLookup:
    """Nearest texel of each chart per grid cell of the chart's box of cells.

    origin (C, 2) int64 (row, col) of each chart's box; shape (C, 2) its (height, width); offset (C,) int64 start of
    its cells in table; table (sum of box areas,) int32 texel per cell, row-major within a box."""

    origin: np.ndarray
    shape: np.ndarray
    offset: np.ndarray
    table: np.ndarray

    def texel(self, chart: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """(N,) int32 texel of chart (N,) at grid cells (row, col) (N,), clamped into the chart's box."""
        h, w = self.shape[chart, 0], self.shape[chart, 1]
        r = np.clip(row - self.origin[chart, 0], 0, h - 1)
        c = np.clip(col - self.origin[chart, 1], 0, w - 1)
        return np.take(self.table, self.offset[chart] + r * w + c)


def chart_lookup(
    texel_index: np.ndarray,
    texel_chart: np.ndarray,
    face_xy: np.ndarray,
    face_chart: np.ndarray,
    positions,
    vertices,
    faces,
    S: int,
) -> ChartLookup:
    """ChartLookup of an S x S atlas: texels at texel_index (T,) in charts texel_chart (T,); faces of charts
    face_chart (F,) with texel coordinates face_xy (F, 3, 2). positions (T, 3) and the mesh (vertices, faces) place
    the charts that hold no texel."""
    C = int(max(face_chart.max(initial=-1), texel_chart.max(initial=-1))) + 1
    rows, cols = np.divmod(np.asarray(texel_index, dtype=np.int64), S)
    lo = np.full((C, 2), S, dtype=np.int64)
    hi = np.full((C, 2), -1, dtype=np.int64)
    cell = np.clip(np.floor(face_xy[..., ::-1]), 0, S - 1).astype(np.int64)  # (F, 3, 2) (row, col)
    np.minimum.at(lo, face_chart, cell.min(1))
    np.maximum.at(hi, face_chart, cell.max(1))
    rc = np.stack([rows, cols], 1)
    np.minimum.at(lo, texel_chart, rc)
    np.maximum.at(hi, texel_chart, rc)
    hi = np.maximum(hi, lo)
    shape = hi - lo + 1
    sizes = shape[:, 0] * shape[:, 1]
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    table = np.empty(int(sizes.sum()), dtype=np.int32)
    order = np.argsort(texel_chart, kind="stable")
    bounds = np.searchsorted(texel_chart[order], np.arange(C + 1))
    lonely = []
    for c in range(C):
        mine = order[bounds[c] : bounds[c + 1]]
        if not mine.size:
            lonely.append(c)
            continue
        h, w = shape[c]
        grid = np.full((h, w), -1, dtype=np.int64)
        grid[rows[mine] - lo[c, 0], cols[mine] - lo[c, 1]] = mine
        if len(mine) < h * w:
            near = distance_transform_edt(grid < 0, return_distances=False, return_indices=True)
            grid = grid[near[0], near[1]]
        table[offset[c] : offset[c] + h * w] = grid.ravel()
    if lonely:  # charts without a texel (degenerate UVs): the texel nearest their faces' centroid in 3-D
        v = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)].mean(1)
        centre = np.stack([v[face_chart == c].mean(0) for c in lonely])
        _, nearest = cKDTree(np.asarray(positions, dtype=np.float64)).query(centre)
        for c, t in zip(lonely, nearest):
            table[offset[c] : offset[c] + sizes[c]] = t
    return ChartLookup(lo, shape, offset, table)


class AtlasHits:
    """TexelHits of a mesh on its atlas (module doc): mesh (MeshData with uvs) the mesh traced, texels its
    rasterised atlas (AtlasTexels), positions and normals (T, 3) the texels'. The per-chart lookup (with the faces'
    charts, atlas_charts.face_charts) and the face normals are made on first use."""

    def __init__(self, mesh: MeshData, texels: AtlasTexels, positions, normals):
        if mesh.uvs is None:
            raise GeometryError(f"mesh file {mesh.source}: atlas hits need the mesh's UVs (make an atlas first)")
        self.mesh = mesh
        self.vertices = np.asarray(mesh.vertices, dtype=np.float64)
        self.faces = np.asarray(mesh.faces, dtype=np.int64)
        self.texel_index = np.asarray(texels.texel_index, dtype=np.int64)
        self.texel_chart = np.asarray(texels.chart, dtype=np.int64)
        self.areas = np.asarray(texels.areas, dtype=np.float64)
        self.positions = np.asarray(positions, dtype=np.float64)
        self.normals = np.asarray(normals, dtype=np.float64)
        self.texture_size = int(texels.texture_size)
        self.face_xy = uv_to_texel_xy(mesh.uvs, self.texture_size)  # (F, 3, 2)
        T = len(self.texel_index)
        for name, value in (("positions", self.positions), ("normals", self.normals)):
            if value.shape != (T, 3):
                raise GeometryError(f"atlas hits of {mesh.source}: '{name}' has shape {value.shape}, expected {(T, 3)}")

    @cached_property
    def emission_size(self) -> float:
        """Edge length (mesh units) photon emission splits the faces to: about a texel's side, sqrt of the median
        texel area (a face may span many texels, and a_f at its centroid would not follow the light over it)."""
        return float(np.sqrt(np.median(self.areas))) if len(self.areas) else 1.0

    @property
    def num_texels(self) -> int:
        return int(len(self.texel_index))

    @property
    def num_faces(self) -> int:
        return int(len(self.faces))

    @cached_property
    def face_chart(self) -> np.ndarray:
        """(F,) int64 chart of each face."""
        return face_charts(self.mesh)

    @cached_property
    def lookup(self) -> ChartLookup:
        return chart_lookup(
            self.texel_index,
            self.texel_chart,
            self.face_xy,
            self.face_chart,
            self.positions,
            self.vertices,
            self.faces,
            self.texture_size,
        )

    @cached_property
    def face_normals(self) -> np.ndarray:
        F = self.num_faces
        centre = self.texels(np.arange(F), np.full((3, F), 1.0 / 3.0))[0]
        return oriented_face_normals(self.vertices, self.faces, self.normals[centre][:, None, :])

    def texels(self, face: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) int32 texel under each point's uv (module doc) and (N,) bool, all True: every hit counts."""
        face = np.asarray(face).astype(np.int64)
        b = np.asarray(bary, dtype=np.float64)
        xy = self.face_xy[face]  # (N, 3, 2)
        x = np.einsum("kn,nk->n", b, xy[..., 0])
        y = np.einsum("kn,nk->n", b, xy[..., 1])
        S = self.texture_size
        col = np.clip(np.floor(x), 0, S - 1).astype(np.int64)
        row = np.clip(np.floor(y), 0, S - 1).astype(np.int64)
        return self.lookup.texel(self.face_chart[face], row, col), np.ones(len(face), dtype=bool)

    def seen_texels(self, face: np.ndarray, bary: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """texels: a ray sees the texel it meets (direction (3, N) is not needed)."""
        return self.texels(face, bary)
