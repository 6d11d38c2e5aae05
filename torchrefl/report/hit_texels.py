"""Hit -> texel: the triangle mesh a relit image is traced against, and where on the texel grid each hit lies.

A run's estimate lives on its texel grid (H, W) (params.npz); a camera ray meets the object's triangle mesh. This
module maps Embree's closest hit (triangle, barycentrics (u, v): hit = (1-u-v) v0 + u v1 + v v2) to continuous
texel coordinates (row, col), texel (row, col)'s centre at integer (row, col), and samples the estimate there:

- a cylindrical scan (`grid_texel_mesh`): the mesh is the scan grid's triangulation (geometry.range_mesh's
  grid_triangulation of the texel positions, as the loader builds it; the seam quads of a full turn are kept when
  they are no longer than the others); vertex k is grid point k, so a hit's texel coordinates are the barycentric
  blend of its corners' (row, col), columns unwrapped across the seam;
- a mesh_views capture (`atlas_texel_mesh`): the mesh whose atlas the maps are (params.npz's `mesh`); a hit's
  texel coordinates are its corners' UVs blended and mapped to the grid (geometry.atlas.uv_to_texel_xy; texel
  (row, col) centred at uv = ((col + 0.5) / W, 1 - (row + 0.5) / H)).

`sample_texels` reads the estimate at those coordinates: bilinear over the four nearest texels with an estimate
(texels outside the run's mask get weight 0 and the rest are renormalised, so chart borders and gutters do not
darken the image) or the nearest texel. Photometric stereo has no depth, hence no mesh (relit on its own grid).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.geometry.atlas import uv_to_texel_xy
from torchrefl.geometry.range_mesh import grid_triangulation

#: a sample whose texels' mask weights sum below this has no estimate (a hit with no estimated texel near it)
MIN_WEIGHT = 1e-6
INTERPOLATIONS = ("bilinear", "nearest")


@dataclass
class TexelMesh:
    """A triangle mesh and the texel coordinates of its face corners.

    vertices: (V, 3) float64 world frame, the run's units; faces: (F, 3) int64;
    corner_texels: (F, 3, 2) float64 continuous (row, col) of each face corner on the (H, W) grid;
    grid_shape: (H, W); wrap: columns close around (a full-turn scan: column W is column 0).
    """

    vertices: np.ndarray
    faces: np.ndarray
    corner_texels: np.ndarray
    grid_shape: tuple[int, int]
    wrap: bool = False

    def texel_coords(self, triangle: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
        """(N, 2) (row, col) of hits on faces triangle (N,) at Embree barycentrics (N, 2)."""
        u, v = barycentric[:, 0:1], barycentric[:, 1:2]
        c = self.corner_texels[triangle]
        return (1.0 - u - v) * c[:, 0] + u * c[:, 1] + v * c[:, 2]

    def face_normals(self, triangle: np.ndarray) -> np.ndarray:
        """(N, 3) unit geometric normals of faces triangle (N,) (the winding's orientation)."""
        p = self.vertices[self.faces[triangle]]
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


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
    return TexelMesh(vertices, faces, np.stack([rows, cols], -1).astype(np.float64), (H, W), wrap)


def atlas_texel_mesh(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, grid_shape) -> TexelMesh:
    """The mesh of a mesh_views run (vertices (V, 3) mm, faces (F, 3), corner uvs (F, 3, 2)) on its (S, S) atlas."""
    S = int(grid_shape[0])
    xy = uv_to_texel_xy(uvs, S)  # texel (row, col) spans [col, col + 1) x [row, row + 1)
    corner = np.stack([xy[..., 1] - 0.5, xy[..., 0] - 0.5], -1)
    return TexelMesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), corner, (S, S), False)


@dataclass
class TexelSamples:
    """The estimate at N texel coordinates (torch).

    pd (N, 3), ps (N, C), sigma (N,), normals (N, 3) unit; estimated (N,) bool: some texel with an estimate
    contributes (the other rows are 0)."""

    pd: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    normals: torch.Tensor
    estimated: torch.Tensor


@dataclass
class TexelImage:
    """The estimate as one image for sampling: image (1, channels, H, W') with pd, ps, sigma, normals and the mask
    weight, each times the mask (W' = W + 1 with column 0 repeated after column W - 1 when the grid wraps);
    ps_channels C; wrap; W the grid's width."""

    image: torch.Tensor
    ps_channels: int
    wrap: bool
    width: int


def texel_image(pd, ps, sigma, normals, mask, *, wrap: bool = False, dtype=torch.float32) -> TexelImage:
    """The TexelImage of an estimate: pd (H, W, 3), ps (H, W, C), sigma (H, W), normals (H, W, 3), mask (H, W)."""
    m = np.asarray(mask, dtype=np.float64)[..., None]
    stack = np.concatenate([pd * m, ps * m, sigma[..., None] * m, normals * m, m], axis=-1)
    if wrap:  # column W is column 0 again
        stack = np.concatenate([stack, stack[:, :1]], axis=1)
    image = torch.from_numpy(np.ascontiguousarray(stack.transpose(2, 0, 1))).to(dtype)[None]
    return TexelImage(image, int(ps.shape[-1]), bool(wrap), int(mask.shape[1]))


def sample_texels(texels: TexelImage, coords: np.ndarray, interpolation: str = "bilinear") -> TexelSamples:
    """The estimate at coords (N, 2) (row, col) on the grid (in texels' dtype): bilinear over the estimated texels
    among the four nearest, or the nearest texel (interpolation "nearest")."""
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation is {interpolation!r}, expected one of {', '.join(INTERPOLATIONS)}")
    _, _, H, Wg = texels.image.shape
    cols = np.asarray(coords[:, 1], dtype=np.float64)
    if texels.wrap:
        cols = np.mod(cols, texels.width)
    x = 2.0 * cols / max(Wg - 1, 1) - 1.0
    y = 2.0 * np.asarray(coords[:, 0], dtype=np.float64) / max(H - 1, 1) - 1.0
    grid = torch.from_numpy(np.stack([x, y], -1)).to(texels.image.dtype)[None, None]
    out = torch.nn.functional.grid_sample(
        texels.image, grid, mode=interpolation, padding_mode="zeros", align_corners=True
    )[0, :, 0].T  # (N, channels)
    C = texels.ps_channels
    weight = out[:, -1]
    estimated = weight > MIN_WEIGHT
    values = out[:, :-1] / weight.clamp_min(MIN_WEIGHT)[:, None] * estimated[:, None]
    n = values[:, 4 + C : 7 + C]
    n = n / n.norm(dim=1, keepdim=True).clamp_min(1e-12)
    return TexelSamples(values[:, :3], values[:, 3 : 3 + C], values[:, 3 + C], n, estimated)
