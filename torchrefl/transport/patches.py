"""Patches for the radiosity level: square blocks of texels on the texel grid, split where the texel
normals disagree (`texel_patches`: a patch does not straddle a fold) and by the region of the Surface's
neighbours (core/texel_neighbours.py: on an atlas the chart, so a block never joins two charts that only sit
side by side in the atlas; on a grid one region); a mesh face belongs to the
patch of the texel at its first vertex (`face_patches`, which relies on the vertex layout of
torchrefl.geometry.range_mesh.grid_triangulation; `face_corners` gives the patches and normals of
all three corners for the form factors' corner rule).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.core.surface import Surface
from torchrefl.errors import ConfigError, GeometryError


@dataclass
class Patches:
    """Q patches made of texels.

    texel_patch: (T,) int64, patch of each valid texel of the Surface (-1 = none).
    centres: (Q, 3) float64, area-weighted mean texel position.
    normals: (Q, 3) float64, unit, normalised area-weighted mean texel normal.
    areas: (Q,) float64, sum of the member texel areas.
    member_offsets: (Q + 1,) int64 and member_texels: (M,) int64, CSR lists of member texels
        (indices into the Surface's texels, increasing within a patch): patch q owns
        member_texels[member_offsets[q]:member_offsets[q + 1]].
    block: (Q, 2) int64, (region * ceil(H / patch_size) + block row, block column) of each patch on the
        texel grid, region that of the Surface's neighbours (0 on a grid; the chart on an atlas) (the patches a
        block was split into at a crease share it).
    patch_size: texels per block side.
    """

    texel_patch: torch.Tensor
    centres: torch.Tensor
    normals: torch.Tensor
    areas: torch.Tensor
    member_offsets: torch.Tensor
    member_texels: torch.Tensor
    block: torch.Tensor
    patch_size: int

    @property
    def num_patches(self) -> int:
        return int(self.centres.shape[0])

    def members(self, q: int) -> torch.Tensor:
        """(n_q,) int64 texel indices of patch q."""
        return self.member_texels[int(self.member_offsets[q]) : int(self.member_offsets[q + 1])]

    def padded(self, *values: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Per-texel values (T, ...) laid out per patch as (Q, K, ...) with K the largest patch,
        zero-padded; also returns the (Q, K) bool mask of real entries as the last element."""
        Q = self.num_patches
        offsets = self.member_offsets
        counts = offsets[1:] - offsets[:-1]
        K = int(counts.max()) if Q else 0
        patch = torch.repeat_interleave(torch.arange(Q), counts)
        slot = torch.arange(len(self.member_texels)) - offsets[:-1][patch]
        mask = torch.zeros(Q, K, dtype=torch.bool)
        mask[patch, slot] = True
        out = []
        for v in values:
            p = torch.zeros((Q, K) + tuple(v.shape[1:]), dtype=v.dtype)
            p[patch, slot] = v[self.member_texels]
            out.append(p)
        return (*out, mask)


def texel_patches(surface: Surface, patch_size: int, split_angle_deg: float = 180.0) -> Patches:
    """Square blocks of patch_size x patch_size texels on the (H, W) texel grid, split at creases.

    Block (i, j) of region g holds the valid texels of region g (surface.neighbours.region: one region on a
    grid, the chart on an atlas) with row // patch_size == i and col // patch_size == j (blocks at the bottom
    and right borders may be smaller); blocks with no valid texel are no patch. A block whose texel normals
    differ by more than split_angle_deg is split (`split_by_normal`): its first texel (lowest index) seeds a
    patch with every texel of the block within split_angle_deg of that texel's normal, the first of the rest
    seeds the next, and so on. A patch thus never straddles a fold or crease, where one shared mean normal,
    form-factor row and irradiance would be wrong for the texels on both sides (180 = never split). Patches are
    numbered by increasing block index (g * ceil(H / patch_size) + i) * ceil(W / patch_size) + j, then by split
    order; patch_size=1 gives one texel per patch, numbered like the texels.
    """
    if isinstance(patch_size, bool) or not isinstance(patch_size, (int, np.integer)) or patch_size < 1:
        raise ConfigError(f"patch_size must be an integer >= 1 (texels per block side), got {patch_size!r}")
    s = int(patch_size)
    H, W = surface.grid_shape
    flat = surface.texel_index.cpu().long()
    row, col = flat // W, flat % W
    bh, bw = -(-H // s), -(-W // s)
    region = torch.from_numpy(np.asarray(surface.neighbours.region, dtype=np.int64))
    block_id = (region * bh + row // s) * bw + (col // s)
    if not (isinstance(split_angle_deg, (int, float, np.number)) and 0.0 <= float(split_angle_deg) <= 180.0):
        raise ConfigError(
            f"split_angle_deg must be a number in [0, 180] (degrees between texel normals that split "
            f"a patch), got {split_angle_deg!r}"
        )
    n = surface.normals.detach().cpu().double()
    part, parts = (
        split_by_normal(block_id, n, math.cos(math.radians(float(split_angle_deg))))
        if s > 1
        else (torch.zeros_like(block_id), 1)
    )
    key = block_id * parts + part
    uniq, texel_patch = torch.unique(key, sorted=True, return_inverse=True)
    uniq = uniq // parts  # the block of each patch
    Q = len(uniq)
    order = torch.argsort(texel_patch, stable=True)
    counts = torch.bincount(texel_patch, minlength=Q)
    offsets = torch.zeros(Q + 1, dtype=torch.int64)
    offsets[1:] = torch.cumsum(counts, 0)

    a = surface.areas.detach().cpu().double()
    x = surface.positions.detach().cpu().double()
    areas = torch.zeros(Q, dtype=torch.float64).index_add_(0, texel_patch, a)
    if (areas <= 0).any():
        q = int(torch.nonzero(areas <= 0)[0])
        raise GeometryError(
            f"surface from {surface.source}: field 'areas' sums to {float(areas[q]):.3g} <= 0 "
            f"over patch {q} (block {int(uniq[q]) // bw}, {int(uniq[q]) % bw}); expected positive texel areas"
        )
    centres = torch.zeros(Q, 3, dtype=torch.float64).index_add_(0, texel_patch, x * a[:, None]) / areas[:, None]
    nsum = torch.zeros(Q, 3, dtype=torch.float64).index_add_(0, texel_patch, n * a[:, None])
    nlen = nsum.norm(dim=1)
    if (nlen <= 1e-9 * areas).any():
        q = int(torch.nonzero(nlen <= 1e-9 * areas)[0])
        raise GeometryError(
            f"surface from {surface.source}: field 'normals' cancel over patch {q} (block "
            f"{int(uniq[q]) // bw}, {int(uniq[q]) % bw}): no mean normal; use a smaller patch_size"
        )
    block = torch.stack([uniq // bw, uniq % bw], dim=1)
    return Patches(
        texel_patch=texel_patch,
        centres=centres,
        normals=nsum / nlen[:, None],
        areas=areas,
        member_offsets=offsets,
        member_texels=order,
        block=block,
        patch_size=s,
    )


def split_by_normal(group: torch.Tensor, normals: torch.Tensor, cos_min: float) -> tuple[torch.Tensor, int]:
    """Split groups of texels where their normals disagree.

    group (T,) int64 group of each texel, normals (T, 3) unit. In each round, the lowest-index texel
    not yet placed in every group seeds a part; the group's unplaced texels whose normal has a dot
    product >= cos_min with the seed's join it. Returns (part (T,) int64: the round each texel joined,
    0 for most; number of rounds). Deterministic; a seed always joins its own part, so every group
    ends within as many rounds as it has texels."""
    T = group.numel()
    part = torch.full((T,), -1, dtype=torch.int64)
    ids, local = torch.unique(group, return_inverse=True)
    rounds = 0
    left = torch.arange(T)
    while left.numel():
        g = local[left]
        seed = torch.full((len(ids),), T, dtype=torch.int64).scatter_reduce(0, g, left, "amin")
        join = (normals[left] * normals[seed[g]]).sum(-1) >= cos_min
        join |= left == seed[g]
        part[left[join]] = rounds
        left = left[~join]
        rounds += 1
    return part, max(rounds, 1)


def face_patches(surface: Surface, patches: Patches) -> np.ndarray:
    """(F,) int64 patch of each mesh face, -1 where the face's first vertex is not a valid texel.

    Assumes the mesh of grid_triangulation: vertex k is grid point k (flat index row * W + col,
    so V == H * W), and each face lists first the grid point it is attributed to (its quad's
    top-left corner for one triangle, the top-right corner for the other). A face thus goes to
    the texel at its first vertex, and a texel owns about one texel of area, shifted by half a
    texel. Raises GeometryError when the surface has no mesh or its vertex count is not H * W.
    """
    where = f"surface from {surface.source}"
    if not surface.has_mesh:
        raise GeometryError(f"{where}: mesh_vertices/mesh_faces are None; form factors need the triangle mesh")
    H, W = surface.grid_shape
    V = len(surface.mesh_vertices)
    if V != H * W:
        raise GeometryError(
            f"{where}: mesh_vertices has {V} vertices, expected H*W = {H * W} (one per grid point, "
            "as grid_triangulation builds it) to map faces to texels"
        )
    faces = np.asarray(surface.mesh_faces)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise GeometryError(f"{where}: mesh_faces has shape {faces.shape}, expected (F, 3)")
    texel_patch = patches.texel_patch.cpu().numpy()
    if len(texel_patch) != surface.num_texels:
        raise GeometryError(
            f"patches.texel_patch has {len(texel_patch)} entries, expected {surface.num_texels} "
            "(one per texel of the surface)"
        )
    grid = np.full(H * W, -1, dtype=np.int64)
    grid[surface.texel_index.cpu().numpy()] = texel_patch
    first = faces[:, 0].astype(np.int64)
    if len(first) and (first.min() < 0 or first.max() >= H * W):
        raise GeometryError(f"{where}: mesh_faces index vertices outside 0..{H * W - 1}")
    return grid[first]


def face_corners(surface: Surface, patches: Patches) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) int64 patch of each mesh face's corners (-1 where the corner is no valid texel) and (F, 3, 3)
    float32 their texel normals (0 there), for hemisphere_form_factors' corner rule. Same mesh layout as
    face_patches (vertex k = grid point k), whose checks it relies on."""
    H, W = surface.grid_shape
    faces = np.asarray(surface.mesh_faces).astype(np.int64)
    grid = np.full(H * W, -1, dtype=np.int64)
    index = surface.texel_index.cpu().numpy()
    grid[index] = patches.texel_patch.cpu().numpy()
    normal = np.zeros((H * W, 3), dtype=np.float32)
    normal[index] = surface.normals.detach().cpu().numpy().astype(np.float32)
    return grid[faces], normal[faces]
