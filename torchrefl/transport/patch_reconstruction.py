"""From patch values to texel values: a plane through the neighbouring patches (radiosity.reconstruction).

The radiosity level gathers the indirect irradiance H per patch (a block of texels), which estimates H at the
patch's centroid. Giving every texel its patch's value, or a Gaussian average of nearby patches' values,
biases the texels at a plate's edge: their neighbourhood lies on one side only, so where H has a gradient
(it rises towards a concave fold) the edge texels get the interior's lower value. On Object E at full size
the lower plate's row nearest the fold gathered 3.5 % too little light that way, and its Pd came out 1.7 %
high.

`linear_reconstruction` instead fits, for every texel, a plane in the texel's tangent plane through the H of
the patches around it (local linear regression: Gaussian weights of the distance to the patch centroids,
patches whose normal is more than `max_angle_deg` from the texel's left out), and takes the plane's value at
the texel. A linear field is reproduced exactly, at an edge too. Where the patches do not determine a slope
(a single patch, or patches in one line) a small ridge on the slope makes it the weighted mean. The result
is one sparse (T, Q) matrix, built once and applied at every evaluation.
A texel whose plane goes below zero (noisy patches extrapolated at an edge) takes its own patch's value instead
(radiosity_level.indirect_irradiance): irradiance is never negative.

The patches around a texel are those of the 3 x 3 blocks of its region around its block (texel_patches' blocks;
on an atlas its chart's), and the patches of the texels one block side away in the eight directions on the
surface (the Surface's neighbours: across an atlas's seams, round a full-turn scan), which on a plain grid are
among the first.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from torchrefl.core.lobe_sampling import tangent_frame
from torchrefl.core.texel_grid import grid_flat
from torchrefl.core.texel_neighbours import TexelNeighbours
from torchrefl.errors import ConfigError

RIDGE = 1e-6  # slope regulariser: RIDGE x (sum of the weights) x pitch^2 on each slope component


def linear_reconstruction(
    neighbours: TexelNeighbours,
    positions,
    normals,
    texel_patch,
    patch_centres,
    patch_normals,
    patch_size: int,
    max_angle_deg: float = 30.0,
) -> torch.Tensor:
    """Sparse (T, Q) float64 operator: texel values = R @ patch values (module docstring).

    neighbours: the Surface's (core/texel_neighbours.py); positions, normals (T, 3); texel_patch (T,) patch of
    each texel; patch_centres, patch_normals (Q, 3); patch_size: texels per patch side (the blocks of
    texel_patches: the neighbourhood is the module docstring's; the Gaussian's std is the patch pitch, the median
    distance between neighbouring centroids)."""
    if isinstance(patch_size, bool) or not isinstance(patch_size, (int, np.integer)) or patch_size < 1:
        raise ConfigError(f"radiosity.patch_size must be an integer >= 1, got {patch_size!r}")
    x = np.asarray(positions, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    tp = np.asarray(texel_patch, dtype=np.int64)
    c = np.asarray(patch_centres, dtype=np.float64)
    cn = np.asarray(patch_normals, dtype=np.float64)
    T, Q = neighbours.num_texels, len(c)
    H, W = neighbours.grid_shape
    # candidates: the patches of the 3 x 3 blocks around the texel's block (a block may hold several patches
    # where it was split at a crease), the texel's own patch first; their number does not grow with the size
    s_ = int(patch_size)
    bh, bw = -(-H // s_), -(-W // s_)
    region = np.asarray(neighbours.region, dtype=np.int64)
    brow, bcol = neighbours.rows // s_, neighbours.cols // s_
    pblock = np.full(Q, -1, dtype=np.int64)
    pblock[tp] = (region * bh + brow) * bw + bcol  # texel_patches' block ids
    order = np.argsort(pblock, kind="stable")
    keys, count = np.unique(pblock[pblock >= 0], return_counts=True)  # the blocks that hold patches
    keys, count = (keys, count) if len(keys) else (np.full(1, -1), np.zeros(1, dtype=np.int64))
    start = np.concatenate([[0], np.cumsum(count)[:-1]]) + int((pblock < 0).sum())
    most = int(count.max()) if Q else 0
    cand = []
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            nb = grid_flat(brow + dr, bcol + dc, (bh, bw))
            key = (region * bh) * bw + nb
            at = np.minimum(np.searchsorted(keys, key), len(keys) - 1)
            ok = (nb >= 0) & (keys[at] == key)
            n_at = np.where(ok, count[at], 0)
            for j in range(most):
                has = ok & (j < n_at)
                cand.append(np.where(has, order[np.minimum(start[at] + j, Q - 1)], -1))
    cand = np.stack(cand, 1) if cand else np.full((T, 0), -1, dtype=np.int64)  # (T, 9 most)
    cand = np.concatenate([tp[:, None], np.where(cand == tp[:, None], -1, cand)], 1)
    cand = _add_surface_neighbours(cand, neighbours, tp, s_)
    valid = cand >= 0
    q = np.maximum(cand, 0)
    valid &= np.einsum("tmi,ti->tm", cn[q], n) >= math.cos(math.radians(max_angle_deg))
    valid[:, 0] = True
    d = c[q] - x[:, None, :]  # (T, M, 3)
    pitch = np.sqrt(np.median(_pitch2(d, valid)))
    w = np.exp(-(d * d).sum(-1) / (2.0 * pitch * pitch)) * valid  # (T, M)
    t1, t2 = tangent_frame(n / np.linalg.norm(n, axis=1, keepdims=True))  # the texel's tangent plane
    A = np.stack([np.ones_like(w), np.einsum("tmi,ti->tm", d, t1), np.einsum("tmi,ti->tm", d, t2)], -1)  # (T, M, 3)
    AtW = A.transpose(0, 2, 1) * w[:, None, :]  # (T, 3, M)
    M = AtW @ A  # (T, 3, 3)
    e1 = plane_intercept_rows(M, RIDGE * pitch * pitch)  # (T, 3)
    coef = np.einsum("ti,tim->tm", e1, AtW)  # (T, M): texel value = sum coef H_q
    keep = valid & (coef != 0)
    rows = np.broadcast_to(np.arange(T)[:, None], cand.shape)[keep]
    vals = coef[keep]
    # rows sum to one up to round-off; make it exact so a constant field stays constant
    vals = vals / np.bincount(rows, weights=vals, minlength=T)[rows]
    return torch.sparse_coo_tensor(
        torch.from_numpy(np.stack([rows, q[keep]])), torch.from_numpy(vals), (T, Q), check_invariants=False
    ).coalesce()


def plane_intercept_rows(moments: np.ndarray, slope_ridge: float) -> np.ndarray:
    """(T, 3) the intercept's row of the weighted least-squares plane a + b u + c v, per texel, from its moments
    (T, 3, 3) = sum_j w_j x_j x_j^T with x_j = (1, u_j, v_j): a = row . sum_j w_j x_j y_j. slope_ridge x sum_j w_j
    is added to the slopes' diagonal (modified in place), so neighbours in a line still determine a."""
    ridge = slope_ridge * moments[:, 0, 0]
    moments[:, 1, 1] += ridge
    moments[:, 2, 2] += ridge
    e1 = np.broadcast_to(np.array([1.0, 0.0, 0.0]), (len(moments), 3))[..., None]
    return np.linalg.solve(moments, e1)[..., 0]


def _add_surface_neighbours(cand: np.ndarray, neighbours: TexelNeighbours, tp: np.ndarray, step: int) -> np.ndarray:
    """cand (T, M) with columns appended for the patches of the texels `step` texels away on the surface in the
    eight directions that cand does not hold yet (-1 where there is none); unchanged when there is no such patch
    (a plain grid)."""
    t = np.arange(len(tp))
    extra = []
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy == 0 and dx == 0:
                continue
            other = neighbours.neighbour(t, dy * step, dx * step)
            p = np.where(other >= 0, tp[np.maximum(other, 0)], -1)
            held = (cand == p[:, None]).any(1)
            for e in extra:
                held |= e == p
            extra.append(np.where(held, -1, p))
    extra = [e for e in extra if (e >= 0).any()]
    return np.concatenate([cand, np.stack(extra, 1)], 1) if extra else cand


def _pitch2(d: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Squared distance from each texel to its nearest other valid patch centroid (the patch pitch)."""
    d2 = np.where(valid, (d * d).sum(-1), np.inf)
    d2[:, 0] = np.inf  # not its own patch
    near = d2.min(1)
    near = near[np.isfinite(near) & (near > 0)]
    return near if near.size else np.ones(1)
