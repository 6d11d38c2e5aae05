"""Density estimation on the texel grid for the photon level: a Gaussian kernel over neighbouring texels,
optionally joint bilateral with the texel normals as guide (a photon map's gather with a normal test).

smooth_on_grid is the normalised kernel as kornia's filters on the grid image. smoothing_matrix, the operator the
photon level applies to its cached irradiance (built once), is the same kernel made local linear: each texel takes
the value at its own cell of the plane fitted, with the kernel's weights, through its neighbours' values. Inside a
region it is the normalised kernel (the neighbourhood is symmetric), and it is tested equal to kornia's there; where
the neighbourhood is one-sided (next to a fold, whose other side the normal test leaves out, and at the scan's
edges) the normalised kernel returns the interior's value and the plane does not: on the fold at full size the
upper plate's three rows next to the crease gathered 2-9 % too little of the light that came by a specular
scattering (docs/results/fold.md). spread_on_grid spreads point entries over their grid neighbours (the specular
entries) with the normalised kernel. torchrefl.transport.cache_build describes where the cache uses each.

The operators' neighbours are the Surface's (core/texel_neighbours.py): the texel at offset (dy, dx) is
neighbours.neighbour(t, dy, dx), so on an atlas a window reaches across chart seams (walking, keeping its heading)
and never takes a texel of another chart that only sits beside it in the atlas; on a full-turn scan it wraps.
smooth_on_grid, kornia's filter on the grid image, is the plain-grid reference the tests compare them with.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import torch

from torchrefl.core.lobe_sampling import column_dot
from torchrefl.core.texel_neighbours import TexelNeighbours, window_offsets
from torchrefl.transport.patch_reconstruction import plane_intercept_rows

KERNEL_PHOTONS = 10_000  # photons of one light under the automatic irradiance kernel (photon.smoothing: null)
SPECULAR_KERNEL_PHOTONS = 5_000  # the same for the spread of the specular entries (photon.specular_smoothing: null)
# the automatic kernels' largest std in texels: the operators hold (2 ceil(3 std) + 1)^2 and (2 round(std) + 1)^2
# neighbours per texel and entry
MAX_AUTO_SMOOTHING = 4.0
MAX_AUTO_SPECULAR_SMOOTHING = 3.0
#: smoothing_matrix builds the window rows of at most this many slots (texel x window offset) at once
ROW_CHUNK_SLOTS = 1 << 23
#: smoothing_matrix's ridge on the plane's slopes, per unit weight (slopes in irradiance per texel)
SLOPE_RIDGE = 1e-3


def kernel_std(photons_per_light: int, texels: int, kernel_photons: int) -> float:
    """The automatic density kernel's std in texels: the Gaussian whose area 4 pi std^2 holds kernel_photons of a
    light's photons_per_light spread over `texels` (a photon map's gather of a fixed photon count, made global:
    resolution-free, and narrower the more photons are traced)."""
    return math.sqrt(kernel_photons * texels / (4.0 * math.pi * max(photons_per_light, 1)))


def density_kernels(photons_per_light: int, texels: int, smoothing, specular_smoothing) -> tuple[float, float]:
    """The density kernels' std in texels (irradiance, specular): photon.smoothing and specular_smoothing as given, or
    where None the automatic ones (kernel_std) capped at MAX_AUTO_SMOOTHING and MAX_AUTO_SPECULAR_SMOOTHING."""
    irradiance = (
        min(kernel_std(photons_per_light, texels, KERNEL_PHOTONS), MAX_AUTO_SMOOTHING)
        if smoothing is None
        else float(smoothing)
    )
    specular = (
        min(kernel_std(photons_per_light, texels, SPECULAR_KERNEL_PHOTONS), MAX_AUTO_SPECULAR_SMOOTHING)
        if specular_smoothing is None
        else float(specular_smoothing)
    )
    return irradiance, specular


def smoother_radius(sigma: float) -> int:
    """smoothing_matrix's window radius (texels) at std sigma."""
    return int(math.ceil(3 * sigma))


def spread_radius(sigma: float) -> int:
    """SpreadKernel's window radius (texels) at std sigma: truncated near the std to bound the copies per entry."""
    return max(1, int(round(sigma)))


def window_slots(smoothing: float, specular_smoothing: float) -> tuple[int, int]:
    """Window offsets per texel of smoothing_matrix at std `smoothing` and of SpreadKernel at `specular_smoothing`
    (0 where the std is not positive: no operator)."""
    smoother = (2 * smoother_radius(smoothing) + 1) ** 2 if smoothing > 0 else 0
    spread = (2 * spread_radius(specular_smoothing) + 1) ** 2 if specular_smoothing > 0 else 0
    return smoother, spread


def photons_for_kernel(std: float, texels: int, kernel_photons: int) -> int:
    """photons_per_light at which the automatic kernel (kernel_std) has std `std` texels."""
    return int(math.ceil(kernel_photons * texels / (4.0 * math.pi * std * std)))


def smooth_on_grid(
    values: torch.Tensor,
    texel_index: torch.Tensor,
    grid_shape: tuple[int, int],
    sigma: float,
    normals: torch.Tensor | None = None,
    normal_sigma: float = 0.0,
) -> torch.Tensor:
    """Normalised Gaussian smoothing (std `sigma` texels) of per-texel values (..., T, C) over the grid;
    with normals (T, 3) and normal_sigma > 0 each neighbour's weight also has the factor
    exp(-|n - n'|^2 / (2 normal_sigma^2)) (joint bilateral filter guided by the normals).

    kornia's filters on the grid image: the reference that smoothing_matrix (the operator the photon level
    applies, built once) is tested against inside a region, where its local plane is this kernel."""
    if sigma <= 0:
        return values
    from kornia.filters import gaussian_blur2d, joint_bilateral_blur

    H, W = grid_shape
    lead, (T, C) = values.shape[:-2], values.shape[-2:]
    flat = values.reshape(-1, T, C).permute(0, 2, 1).reshape(-1, T)  # (B*C, T)
    grid = torch.zeros(flat.shape[0] + 1, H * W, dtype=values.dtype)
    grid[:-1, texel_index] = flat
    grid[-1, texel_index] = 1.0  # the valid mask
    k = 2 * int(math.ceil(3 * sigma)) + 1
    if normals is not None and normal_sigma > 0:
        guide = torch.zeros(3, H * W, dtype=values.dtype)
        guide[:, texel_index] = normals.to(values.dtype).t()
        blurred = joint_bilateral_blur(
            grid.reshape(1, -1, H, W),
            guide.reshape(1, 3, H, W),
            (k, k),
            float(normal_sigma),
            (sigma, sigma),
            border_type="constant",
            color_distance_type="l2",
        )
    else:
        blurred = gaussian_blur2d(grid.reshape(1, -1, H, W), (k, k), (sigma, sigma), border_type="constant")
    blurred = blurred.reshape(-1, H * W)[:, texel_index]
    out = blurred[:-1] / blurred[-1:].clamp_min(1e-12)
    return out.reshape(-1, C, T).permute(0, 2, 1).reshape(*lead, T, C)


def _grid_neighbours(neighbours: TexelNeighbours, sigma: float, radius: int, normals=None, normal_sigma: float = 0.0):
    """The kernel shared by spread_on_grid and smoothing_matrix: a function of t_from (M,) that yields, per grid
    offset within `radius` (window_offsets), (t_to (M,), weight (M,)): the texel at that offset on the surface
    (neighbours.neighbour; -1 where there is none) and exp(-|offset|^2 / (2 sigma^2)) times, with normals (T, 3)
    and normal_sigma > 0, exp(-|n - n'|^2 / (2 normal_sigma^2)) (kornia's joint bilateral weights with the normals
    as guide)."""
    nrm = (
        None if normals is None or normal_sigma <= 0 else np.ascontiguousarray(np.asarray(normals, dtype=np.float64).T)
    )
    offsets = window_offsets(radius)

    def kernel(t_from: np.ndarray):
        n_from = None if nrm is None else np.take(nrm, t_from, axis=1)
        for dy, dx in offsets:
            to = neighbours.neighbour(t_from, dy, dx)
            w = np.where(to >= 0, math.exp(-(dy * dy + dx * dx) / (2.0 * sigma * sigma)), 0.0)
            if n_from is not None:
                d = n_from - np.take(nrm, np.maximum(to, 0), axis=1)
                w *= np.exp(-column_dot(d, d) / (2.0 * normal_sigma**2))
            yield to, w

    return kernel


def smoothing_matrix(
    neighbours: TexelNeighbours, sigma: float, normals=None, normal_sigma: float = 0.0
) -> torch.Tensor:
    """Local linear smoothing as a sparse (T, T) float64 operator (rows sum to one), built once and applied at
    every evaluation. Each texel's value is the intercept of the weighted least-squares plane a + b dy + c dx
    through the values of the texels at offsets (dy, dx) on the surface (the Surface's neighbours) within radius
    ceil(3 sigma), weighted by
    smooth_on_grid's kernel (Gaussian of std sigma texels, times the normal test with normals (T, 3) and
    normal_sigma > 0): the normalised kernel wherever the weighted neighbourhood is symmetric, and free of its
    bias where it is one-sided (a linear field is kept, up to the ridge). A small ridge on the slopes
    (SLOPE_RIDGE) keeps them determined where the neighbours lie in a line; the weights can be negative at an
    edge."""
    T = neighbours.num_texels
    radius = smoother_radius(sigma)
    kernel = _grid_neighbours(neighbours, sigma, radius, normals, normal_sigma)
    offsets = window_offsets(radius)
    K = len(offsets)
    index = np.int32 if T < 2**31 else np.int64
    # the entries, written a chunk of rows at a time into arrays sized for every window slot: the pages never written
    # are never resident, so the build takes what the operator keeps (12 bytes an entry) and one chunk's temporaries
    # (a COO tensor from per-offset parts took about 110 bytes a slot: 20 GB for a 313 808-texel atlas at 4 texels)
    col_all, val_all = np.empty(T * K, dtype=index), np.empty(T * K)
    counts, nnz = np.zeros(T, dtype=np.int64), 0
    step = max(1, ROW_CHUNK_SLOTS // K)
    for start in range(0, T, step):
        rows = np.arange(start, min(T, start + step))
        col, val, counts[rows] = _window_rows(rows, kernel, offsets, index, T)
        col_all[nnz : nnz + col.size], val_all[nnz : nnz + col.size] = col, val
        nnz += col.size
    crow = np.concatenate([[0], np.cumsum(counts)]).astype(index)
    with warnings.catch_warnings():  # torch calls its CSR support beta
        warnings.simplefilter("ignore", UserWarning)
        return torch.sparse_csr_tensor(
            torch.from_numpy(crow),
            torch.from_numpy(col_all[:nnz]),
            torch.from_numpy(val_all[:nnz]),
            (T, T),
            check_invariants=False,
        )


def _window_rows(rows: np.ndarray, kernel, offsets: list, index, T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """smoothing_matrix's rows `rows` (n,): (their entries' columns and values, row by row with each row's columns
    sorted and repeated columns summed, as a COO tensor's coalesce gives them; the entries per row (n,))."""
    n = rows.size
    cols, vals = np.full((n, len(offsets)), -1, dtype=index), np.zeros((n, len(offsets)))
    moments = np.zeros((n, 3, 3))
    for k, ((dy, dx), (to, w)) in enumerate(zip(offsets, kernel(rows))):
        keep = np.flatnonzero((to >= 0) & (w > 0))
        wk = np.take(w, keep)
        design = np.array([1.0, dy, dx])
        moments[keep] += wk[:, None, None] * np.outer(design, design)
        cols[keep, k] = np.take(to, keep)
        vals[keep, k] = wk
    e1 = plane_intercept_rows(moments, SLOPE_RIDGE)  # the radiosity level's reconstruction solves the same plane
    del moments
    total = np.zeros(n)  # each row's sum, added offset by offset
    for k, (dy, dx) in enumerate(offsets):
        keep = np.flatnonzero(cols[:, k] >= 0)
        v = np.take(vals[:, k], keep) * (np.take(e1, keep, axis=0) @ np.array([1.0, dy, dx]))
        vals[keep, k] = v
        total[keep] += v
    present = cols >= 0
    np.divide(vals, total[:, None], out=vals, where=present)  # rows sum to one up to round-off: make it exact
    counts = present.sum(1)
    col, val = cols[present], vals[present]  # row by row
    del cols, vals
    row = np.repeat(np.arange(n), counts)
    if not np.all((row[1:] != row[:-1]) | (col[1:] > col[:-1])):  # a window's order is not the columns' (an atlas)
        order = np.argsort(row * T + col, kind="stable")
        col, val, row = np.take(col, order), np.take(val, order), np.take(row, order)
        new = np.ones(col.size, dtype=bool)
        np.logical_or(col[1:] != col[:-1], row[1:] != row[:-1], out=new[1:])
        if not new.all():  # a texel reached by two offsets (an atlas walk across a seam): one entry, summed
            val = np.bincount(np.cumsum(new) - 1, weights=val)
            col = col[new]
            counts = np.bincount(row[new], minlength=n)
    return col, val, counts


def apply_on_grid(matrix: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """A (T, T) sparse operator (smoothing_matrix) applied to per-texel values (..., T, C); differentiable."""
    lead, (T, C) = values.shape[:-2], values.shape[-2:]
    flat = values.reshape(-1, T, C).permute(1, 0, 2).reshape(T, -1)
    out = torch.sparse.mm(matrix.to(values.dtype), flat)
    return out.reshape(T, -1, C).permute(1, 0, 2).reshape(*lead, T, C)


def spread_on_grid(
    obs: np.ndarray,
    T: int,
    neighbours: TexelNeighbours,
    sigma: float,
    normals=None,
    normal_sigma: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Spread point entries at flat observation indices obs = p T + t over the neighbours of t on the surface, with the
    kernel of smooth_on_grid (Gaussian of std `sigma` texels, truncated at radius max(1, round(sigma)) to bound the
    number of copies, times the normal test)
    normalised at each receiving texel (normalised convolution: a constant field stays constant).
    Returns (obs of the copies, index of the entry each copy comes from, weight of each copy). SpreadKernel is the
    same built once, for many calls."""
    return SpreadKernel(neighbours, sigma, normals, normal_sigma)(obs, T)


class SpreadKernel:
    """spread_on_grid's kernel built once (the weights of every texel's copies, normalised at their receivers), applied
    to many entries without recomputing it: the same copies, in the same order, with the same weights to the bit."""

    def __init__(self, neighbours: TexelNeighbours, sigma: float, normals=None, normal_sigma: float = 0.0):
        n = neighbours.num_texels
        kernel = _grid_neighbours(neighbours, sigma, spread_radius(sigma), normals, normal_sigma)
        mass = np.zeros(n)
        src, to, weight, offset = [], [], [], []
        for k, (t_to, w) in enumerate(kernel(np.arange(n))):
            mass += np.bincount(np.maximum(t_to, 0), weights=np.where(t_to >= 0, w, 0.0), minlength=n)
            keep = np.flatnonzero((t_to >= 0) & (w > 0))
            src.append(keep)
            to.append(np.take(t_to, keep))
            weight.append(np.take(w, keep))
            offset.append(np.full(keep.size, k, dtype=np.int16))
        src = np.concatenate(src)
        order = np.argsort(src, kind="stable")  # texel by texel, each texel's copies in the window's order
        self.to = np.take(np.concatenate(to), order).astype(np.int32 if n < 2**31 else np.int64)  # 4 bytes a copy
        self.weight = np.take(np.concatenate(weight), order) / np.take(mass, self.to)
        self.offset = np.take(np.concatenate(offset), order)
        self.start = np.concatenate([[0], np.cumsum(np.bincount(src, minlength=n))])

    def __call__(self, obs: np.ndarray, T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(obs of the copies, index of the entry each copy comes from, weight of each copy) of the entries at flat
        observations obs (M,) = p T + t, window offset by window offset (spread_on_grid's order)."""
        obs = np.asarray(obs, dtype=np.int64)
        t_e, p_e = obs % T, obs // T
        first = np.take(self.start, t_e)
        count = np.take(self.start, t_e + 1) - first
        entry = np.repeat(np.arange(obs.size), count)
        base = np.cumsum(count) - count  # where each entry's copies begin among all copies
        pos = np.repeat(first - base, count) + np.arange(entry.size)
        order = np.argsort(np.take(self.offset, pos), kind="stable")  # offset by offset, entries in order
        pos, entry = np.take(pos, order), np.take(entry, order)
        dest = np.take(self.to, pos)
        return np.take(p_e, entry) * T + dest, entry, np.take(self.weight, pos)
