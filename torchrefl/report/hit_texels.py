"""Hit -> texel: the triangle mesh a relit image is traced against, and which texels of the grid each hit reads.

A run's estimate lives on its texel grid (H, W) (params.npz); a camera ray meets the object's triangle mesh. This
module maps Embree's closest hit (triangle, barycentrics (u, v): hit = (1-u-v) v0 + u v1 + v v2) to texels of the
grid with weights (TexelWeights), and samples the estimate with them (sample_texels). Texel coordinates (row, col)
are continuous, texel (row, col)'s centre at integer (row, col):

- a cylindrical scan (`grid_texel_mesh`): the mesh is the scan grid's triangulation (geometry.range_mesh's
  grid_triangulation of the texel positions, as the loader builds it; the seam quads of a full turn are kept when
  they are no longer than the others); vertex k is grid point k, so a hit's texel coordinates are the barycentric
  blend of its corners' (row, col), columns unwrapped across the seam. Bilinear: the four nearest texels;
  nearest: the texel at the rounded coordinates;
- a mesh_views capture (`atlas_texel_mesh`): the mesh whose atlas the maps are (params.npz's `mesh`); a hit's
  texel coordinates are its corners' UVs blended and mapped to the grid (geometry.atlas.uv_to_texel_xy; texel
  (row, col) centred at uv = ((col + 0.5) / W, 1 - (row + 0.5) / H)). The texels are the transport's
  (geometry.atlas_hits.AtlasHits of the mesh's rasterised atlas), and a hit reads only texels of its own face's
  chart: bilinear over those of the four nearest texels that belong to the chart, or, where none does (a gutter
  cell, a chart border cell whose neighbours are another chart's, a UV sphere's pole row without texel centres),
  the chart's texel nearest the hit's cell (AtlasHits.texels, the ChartLookup the transport uses); nearest: that
  texel always.

`sample_texels` reads the estimate with those weights; texels outside the run's mask (no estimate) get weight 0 and
the rest are renormalised, so chart borders and gutters do not darken the image; `sample_table` reads any per-texel
values so (a `value_table`: the relighting's indirect light). Photometric stereo has no depth,
hence no mesh (relit on its own grid).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch

from torchrefl.geometry.atlas import rasterise_atlas, uv_to_texel_xy
from torchrefl.geometry.atlas_hits import AtlasHits
from torchrefl.geometry.atlas_surface import texel_geometry
from torchrefl.geometry.mesh_file import MeshData
from torchrefl.geometry.mesh_normals import corner_normals
from torchrefl.geometry.range_mesh import grid_triangulation

#: a sample whose texels' mask weights sum below this has no estimate (a hit with no estimated texel near it)
MIN_WEIGHT = 1e-6
INTERPOLATIONS = ("bilinear", "nearest")


@dataclass
class TexelWeights:
    """The texels N hits read: index (N, K) int64 flat grid indices row * W + col, weight (N, K) float64 (0 for a
    texel that does not count; a row's weights sum to 1 where some texel counts)."""

    index: np.ndarray
    weight: np.ndarray


@dataclass
class TexelMesh:
    """A triangle mesh and the texel coordinates of its face corners.

    vertices: (V, 3) float64 world frame, the run's units; faces: (F, 3) int64;
    corner_texels: (F, 3, 2) float64 continuous (row, col) of each face corner on the (H, W) grid;
    corner_normals: (F, 3, 3) float64 unit normal at each face corner (the loader's: a scan's texel normals, a
    mesh's geometry.mesh_normals.corner_normals);
    grid_shape: (H, W); wrap: columns close around (a full-turn scan: column W is column 0);
    atlas: the atlas's texels and chart lookup (a mesh_views mesh; None for a scan grid).
    """

    vertices: np.ndarray
    faces: np.ndarray
    corner_texels: np.ndarray
    corner_normals: np.ndarray
    grid_shape: tuple[int, int]
    wrap: bool = False
    atlas: AtlasHits | None = None

    def texel_coords(self, triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """(N, 2) (row, col) of hits on faces triangle (N,) at Embree barycentrics (N, 2)."""
        u, v = barycentric[:, 0:1], barycentric[:, 1:2]
        c = self.corner_texels[triangle]
        return (1.0 - u - v) * c[:, 0] + u * c[:, 1] + v * c[:, 2]

    def normals(self, triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """(N, 3) unit shading normals of hits: their face's corner normals blended at the barycentrics (N, 2), as
        the loader blends them at texel centres (a blend that vanishes keeps the face's first corner normal)."""
        u, v = barycentric[:, 0:1], barycentric[:, 1:2]
        c = self.corner_normals[triangle]
        n = (1.0 - u - v) * c[:, 0] + u * c[:, 1] + v * c[:, 2]
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(length > 1e-12, n / np.maximum(length, 1e-300), c[:, 0])

    def texel_weights(self, triangle: np.ndarray, barycentric: np.ndarray, interpolation: str) -> TexelWeights:
        """The texels hits on faces triangle (N,) at Embree barycentrics (N, 2) read (module doc): interpolation
        "bilinear" or "nearest"."""
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation is {interpolation!r}, expected one of {', '.join(INTERPOLATIONS)}")
        coords = self.texel_coords(triangle, barycentric)
        if self.atlas is None:
            stencil = bilinear_weights if interpolation == "bilinear" else nearest_weights
            return stencil(coords, self.grid_shape, self.wrap)
        if interpolation == "nearest":
            near = self._chart_nearest(triangle, barycentric)
            return TexelWeights(near[:, None], np.ones((len(near), 1)))
        w = bilinear_weights(coords, self.grid_shape)
        weight = np.where(self.cell_chart[w.index] == self.atlas.face_chart[triangle][:, None], w.weight, 0.0)
        total = weight.sum(1)
        none = np.flatnonzero(total <= 0.0)  # no texel of the hit's chart among the four: its chart's nearest
        weight /= np.where(total > 0.0, total, 1.0)[:, None]
        w.index[none] = self._chart_nearest(triangle[none], barycentric[none])[:, None]
        weight[none] = np.eye(1, 4)
        return TexelWeights(w.index, weight)

    def _chart_nearest(self, triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """(N,) flat grid index of the texel of each hit's chart nearest its grid cell (AtlasHits.texels)."""
        bary = np.stack([1.0 - barycentric.sum(1), barycentric[:, 0], barycentric[:, 1]])
        return self.atlas.texel_index[self.atlas.texels(triangle, bary)[0]]

    @cached_property
    def cell_chart(self) -> np.ndarray:
        """(H * W,) int64 chart of the texel in each grid cell, -1 where there is none (an atlas's gutter)."""
        H, W = self.grid_shape
        out = np.full(H * W, -1, dtype=np.int64)
        if self.atlas is not None:
            out[self.atlas.texel_index] = self.atlas.texel_chart
        return out


def bilinear_weights(coords: np.ndarray, grid_shape, wrap: bool = False) -> TexelWeights:
    """The four texels nearest continuous (row, col) coords (N, 2) on a (H, W) grid with their bilinear weights
    (texels off the grid weigh 0; wrap: column W is column 0)."""
    H, W = grid_shape
    r0, c0 = np.floor(coords[:, 0]), np.floor(coords[:, 1])
    fr, fc = (coords[:, 0] - r0)[:, None], (coords[:, 1] - c0)[:, None]
    down, right = np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1])  # the corners (r0, c0) .. (r0 + 1, c0 + 1)
    weight = np.where(down == 1, fr, 1.0 - fr) * np.where(right == 1, fc, 1.0 - fc)
    rows, cols = r0.astype(np.int64)[:, None] + down, c0.astype(np.int64)[:, None] + right
    return _on_grid(rows, cols, weight, H, W, wrap)


def nearest_weights(coords: np.ndarray, grid_shape, wrap: bool = False) -> TexelWeights:
    """The texel nearest each of coords (N, 2) (row, col) on a (H, W) grid, weight 1 (0 off the grid)."""
    H, W = grid_shape
    rows, cols = (np.floor(coords[:, k] + 0.5).astype(np.int64)[:, None] for k in (0, 1))
    return _on_grid(rows, cols, np.ones(rows.shape), H, W, wrap)


def _on_grid(rows, cols, weight, H: int, W: int, wrap: bool) -> TexelWeights:
    cols = np.mod(cols, W) if wrap else cols
    inside = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
    return TexelWeights(np.where(inside, rows * W + cols, 0), np.where(inside, weight, 0.0))


def geometry_mask(normals: np.ndarray) -> np.ndarray:
    """(H, W) bool: grid points that carry geometry (params.npz writes unit normals there, zeros elsewhere)."""
    return np.linalg.norm(normals, axis=-1) > 0.5


def grid_texel_mesh(positions: np.ndarray, normals: np.ndarray) -> TexelMesh:
    """The scan grid's triangulation (positions, normals (H, W, 3) of params.npz) as a TexelMesh."""
    H, W = positions.shape[:2]
    valid = geometry_mask(normals)
    vertices, faces = grid_triangulation(positions.astype(np.float64), valid, wrap=True)
    rows, cols = faces // W, (faces % W).astype(np.float64)
    seam = cols.max(axis=1, keepdims=True) - cols > W / 2  # corners on column 0 of a quad across the seam
    cols = np.where(seam, cols + W, cols)
    wrap = bool(seam.any())
    n = normals.reshape(-1, 3).astype(np.float64)[faces]
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)
    return TexelMesh(vertices, faces, np.stack([rows, cols], -1).astype(np.float64), n, (H, W), wrap)


def atlas_texel_mesh(mesh: MeshData, grid_shape) -> TexelMesh:
    """The mesh of a mesh_views run (MeshData with UVs, mm) on its (S, S) atlas, with the atlas's texels as the
    loader rasterises them (geometry.atlas.rasterise_atlas) and their chart lookup (geometry.atlas_hits)."""
    S = int(grid_shape[0])
    xy = uv_to_texel_xy(mesh.uvs, S)  # texel (row, col) spans [col, col + 1) x [row, row + 1)
    corner = np.stack([xy[..., 1] - 0.5, xy[..., 0] - 0.5], -1)
    texels = rasterise_atlas(mesh, S)
    atlas = AtlasHits(mesh, texels, *texel_geometry(mesh, texels))
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    return TexelMesh(vertices, faces, corner, corner_normals(vertices, faces), (S, S), False, atlas)


@dataclass
class TexelSamples:
    """The estimate read at N hits (torch): pd (N, 3), ps (N, C), sigma (N,); estimated (N,) bool: some texel with
    an estimate contributes (the other rows are 0)."""

    pd: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    estimated: torch.Tensor


@dataclass
class TexelImage:
    """The estimate as one table for sampling: table (H * W, C + 5) with pd, ps, sigma and the mask weight per grid
    cell (row-major), each times the mask; ps_channels C."""

    table: torch.Tensor
    ps_channels: int


def value_table(values: np.ndarray, mask, *, dtype=torch.float32) -> torch.Tensor:
    """(H * W, C + 1) per-texel values (H, W, C) times the mask (H, W), and the mask, row-major: a table for
    sample_table."""
    m = np.asarray(mask, dtype=np.float64)[..., None]
    stack = np.concatenate([np.asarray(values, dtype=np.float64) * m, m], axis=-1)
    return torch.from_numpy(np.ascontiguousarray(stack.reshape(-1, stack.shape[-1]))).to(dtype)


def texel_image(pd, ps, sigma, mask, *, dtype=torch.float32) -> TexelImage:
    """The TexelImage of an estimate: pd (H, W, 3), ps (H, W, C), sigma (H, W), mask (H, W)."""
    stack = np.concatenate([pd, ps, np.asarray(sigma)[..., None]], axis=-1)
    return TexelImage(value_table(stack, mask, dtype=dtype), int(ps.shape[-1]))


def sample_table(table: torch.Tensor, weights: TexelWeights) -> tuple[torch.Tensor, torch.Tensor]:
    """(values (N, C), estimated (N,) bool) of a value_table (H * W, C + 1) read with weights (in the table's
    dtype): the weighted mean over the masked texels among each hit's (module doc); 0 where none counts."""
    w = torch.from_numpy(weights.weight).to(table.dtype)
    out = (w[..., None] * table[torch.from_numpy(weights.index)]).sum(1)  # (N, C + 1)
    weight = out[:, -1]
    estimated = weight > MIN_WEIGHT
    return out[:, :-1] / weight.clamp_min(MIN_WEIGHT)[:, None] * estimated[:, None], estimated


def sample_texels(texels: TexelImage, weights: TexelWeights) -> TexelSamples:
    """The estimate read with weights (in texels' dtype): the weighted mean over the estimated texels among each
    hit's (module doc)."""
    values, estimated = sample_table(texels.table, weights)
    C = texels.ps_channels
    return TexelSamples(values[:, :3], values[:, 3 : 3 + C], values[:, 3 + C], estimated)
