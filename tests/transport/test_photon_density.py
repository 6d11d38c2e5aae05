"""The photon level's density estimation on the texel grid: the local linear smoothing operator against a slow
per-texel least-squares reference and kornia's filter, its behaviour next to a fold, and the automatic kernel
(photon.smoothing / specular_smoothing: null): the same noise at any resolution."""

import numpy as np
import pytest
import torch
from conftest import fold_surface

from torchrefl.core.texel_grid import TexelGrid
from torchrefl.transport.photon_density import (
    KERNEL_PHOTONS,
    SLOPE_RIDGE,
    SpreadKernel,
    apply_on_grid,
    kernel_std,
    smooth_on_grid,
    smoothing_matrix,
    spread_on_grid,
)


def plane_fit_reference(values, texel_index, grid_shape, sigma, normals=None, normal_sigma=0.0):
    """Per texel and by loops: the weighted least-squares plane a + b dy + c dx through the neighbours within
    ceil(3 sigma) (Gaussian weights times the normal test, SLOPE_RIDGE on the slopes), evaluated at the texel."""
    H, W = grid_shape
    index = np.asarray(texel_index)
    slot = {int(c): t for t, c in enumerate(index)}
    radius = int(np.ceil(3 * sigma))
    out = np.zeros_like(values)
    for t, cell in enumerate(index):
        r, c = divmod(int(cell), W)
        A, w, y = [], [], []
        for dy in range(-radius, radius + 1):
            for dx in range(-radius, radius + 1):
                if not (0 <= r + dy < H and 0 <= c + dx < W) or (r + dy) * W + c + dx not in slot:
                    continue
                j = slot[(r + dy) * W + c + dx]
                wt = np.exp(-(dy * dy + dx * dx) / (2 * sigma * sigma))
                if normals is not None and normal_sigma > 0:
                    wt *= np.exp(-np.sum((normals[t] - normals[j]) ** 2) / (2 * normal_sigma**2))
                A.append([1.0, dy, dx])
                w.append(wt)
                y.append(values[j])
        A, w, y = np.array(A), np.array(w), np.array(y)
        lhs = A.T @ (w[:, None] * A) + np.diag([0.0, 1.0, 1.0]) * SLOPE_RIDGE * w.sum()
        out[t] = np.linalg.solve(lhs, A.T @ (w[:, None] * y))[0]
    return out


@pytest.mark.parametrize("sigma,normal_sigma", [(1.0, 0.0), (1.0, 0.1), (0.7, 0.3), (2.0, 0.1)])
def test_the_smoothing_operator_is_the_local_plane_fit(sigma, normal_sigma):
    """smoothing_matrix applied to a random field equals the per-texel weighted plane fit, on a fold with a hole
    in its texel set; it is differentiable (float64 gradcheck)."""
    s = fold_surface(12, 20)
    keep = torch.ones(s.num_texels, dtype=torch.bool)
    keep[45:52] = False  # texels missing from the set
    index, normals = s.texel_index[keep].numpy(), s.normals[keep].numpy()
    values = np.random.default_rng(0).random((len(index), 3))
    M = smoothing_matrix(TexelGrid(index, s.grid_shape), sigma, normals, normal_sigma)
    ref = plane_fit_reference(values, index, s.grid_shape, sigma, normals, normal_sigma)
    np.testing.assert_allclose(apply_on_grid(M, torch.from_numpy(values)[None])[0].numpy(), ref, rtol=1e-9, atol=1e-12)
    assert torch.autograd.gradcheck(lambda v: apply_on_grid(M, v), (torch.from_numpy(values)[None].requires_grad_(),))


@pytest.mark.parametrize("sigma,normal_sigma", [(1.0, 0.0), (1.0, 0.1), (2.0, 0.1)])
def test_inside_a_region_the_operator_is_kornias_normalised_filter(sigma, normal_sigma):
    """Where a texel's whole window lies on its own plate and inside the texel set, the plane's intercept is the
    normalised kernel's mean: smoothing_matrix equals smooth_on_grid (kornia's Gaussian or joint bilateral)."""
    s = fold_surface(16, 40)
    index, normals = s.texel_index.numpy(), s.normals
    values = torch.rand(2, s.num_texels, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    M = smoothing_matrix(TexelGrid(index, s.grid_shape), sigma, normals.numpy(), normal_sigma)
    ref = smooth_on_grid(values, s.texel_index, s.grid_shape, sigma, normals if normal_sigma else None, normal_sigma)
    r, c = index // 40, index % 40
    radius = int(np.ceil(3 * sigma))
    inner = (r >= radius) & (r < 16 - radius) & (c >= radius) & (c < 20 - radius)  # the floor: columns 0-19
    assert inner.sum() > 20
    torch.testing.assert_close(apply_on_grid(M, values)[:, inner], ref[:, inner], rtol=1e-9, atol=1e-12)


def test_a_ramp_towards_a_fold_is_kept_where_the_normalised_kernel_flattens_it():
    """Indirect light that rises towards a concave fold, as a linear ramp on each plate: with the normal test both
    operators gather on the texel's own plate only, and the normalised kernel (smooth_on_grid) returns the
    interior's lower value at the columns next to the fold; the local plane keeps the ramp there."""
    s = fold_surface(12, 40)
    col = s.texel_index.numpy() % 40
    ramp = torch.from_numpy(1.0 + 0.1 * np.minimum(col, 39 - col))[None, :, None].expand(1, -1, 3).double()
    M = smoothing_matrix(s.neighbours, 2.0, s.normals.numpy(), 0.1)
    plane = apply_on_grid(M, ramp)[0, :, 0].numpy()
    normalised = smooth_on_grid(ramp, s.texel_index, s.grid_shape, 2.0, s.normals, 0.1)[0, :, 0].numpy()
    at_fold = (col == 19) | (col == 20)
    truth = ramp[0, :, 0].numpy()
    np.testing.assert_allclose(plane[at_fold], truth[at_fold], rtol=2e-3)
    assert (truth[at_fold] - normalised[at_fold]).min() > 0.1  # about 1.6 texels of ramp lost


def smoothed_noise(rows: int, cols: int, photons: int, seed: int = 0) -> float:
    """Relative std of the smoothed photon count of a uniformly lit rows x cols grid (interior texels)."""
    rng = np.random.default_rng(seed)
    T = rows * cols
    counts = np.bincount(rng.integers(0, T, size=photons), minlength=T).astype(np.float64)
    std = kernel_std(photons, T, KERNEL_PHOTONS)
    M = smoothing_matrix(TexelGrid(np.arange(T), (rows, cols)), std)
    smooth = torch.sparse.mm(M, torch.from_numpy(counts)[:, None]).numpy()[:, 0].reshape(rows, cols)
    pad = int(np.ceil(3 * std))
    inner = smooth[pad:-pad, pad:-pad]
    return float(inner.std() / inner.mean())


def test_the_automatic_kernel_gives_the_same_noise_at_any_resolution():
    """Four times the texels at the same photon count: the kernel doubles in texels (the same width on the
    object), so the smoothed irradiance is as noisy as before; a fixed kernel in texels would be twice as noisy."""
    coarse = smoothed_noise(60, 60, 400_000)
    fine = smoothed_noise(120, 120, 400_000)
    assert kernel_std(400_000, 120 * 120, KERNEL_PHOTONS) == pytest.approx(
        2 * kernel_std(400_000, 60 * 60, KERNEL_PHOTONS)
    )
    assert fine == pytest.approx(coarse, rel=0.2)
    # Poisson counts under a normalised Gaussian: relative std 1 / sqrt(n 4 pi std^2) = 1 / sqrt(KERNEL_PHOTONS)
    assert coarse == pytest.approx(1 / np.sqrt(KERNEL_PHOTONS), rel=0.15)


def test_more_photons_narrow_the_automatic_kernel():
    assert kernel_std(1_600_000, 34_449, KERNEL_PHOTONS) == pytest.approx(
        kernel_std(400_000, 34_449, KERNEL_PHOTONS) / 2
    )


def test_on_an_atlas_the_kernel_gathers_on_the_surface_not_from_charts_beside_it_in_the_atlas():
    """The cube's charts sit one gutter texel apart in the atlas, so a radius-3 grid window reaches the chart
    beside it, whose texels are a face away in 3-D (the plain grid's operator has such entries). On the Surface's
    neighbours every entry joins texels within the window's reach on the surface (3 sqrt(2) mm), and entries
    across the cube's edges exist."""
    from conftest import atlas_cube

    s = atlas_cube(side=8, gap=1).surface
    p, chart = s.positions.numpy(), s.extras["chart"]

    def reach(M):
        i, j = M.to_sparse_coo().indices().numpy()
        return np.linalg.norm(p[i] - p[j], axis=1), chart[i] != chart[j]

    d, cross = reach(smoothing_matrix(s.neighbours, 1.0))
    assert d.max() <= 3 * np.sqrt(2) + 1e-9 and cross.any()
    d_plain, _ = reach(smoothing_matrix(TexelGrid(s.texel_index.numpy(), s.grid_shape), 1.0))
    assert d_plain.max() > 6.0
    obs = np.arange(s.num_texels)
    to, src, _ = spread_on_grid(obs, s.num_texels, s.neighbours, 1.0)
    assert np.linalg.norm(p[to] - p[obs[src]], axis=1).max() <= np.sqrt(2) + 1e-9


def test_the_spread_kernel_built_once_gives_the_copies_of_a_walk_over_the_window():
    """SpreadKernel (spread_on_grid's kernel built once for every refresh) against the spread by hand: for each
    window offset in turn, every entry's copy at that neighbour, weighted by the Gaussian times the normal test and
    divided by the receiving texel's total weight; the same copies in the same order (the merge sums them in that
    order), the weights to rounding."""
    rng = np.random.default_rng(4)
    H, W = 9, 11
    grid = TexelGrid(np.flatnonzero(rng.random(H * W) > 0.2), (H, W))
    T, sigma, ns = grid.num_texels, 1.4, 0.3
    normals = rng.normal(size=(T, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    obs = rng.integers(0, 3 * T, 40)
    offsets = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]  # radius round(1.4) = 1

    def weight(t, u, dy, dx):
        d = normals[t] - normals[u]
        return np.exp(-(dy * dy + dx * dx) / (2 * sigma**2)) * np.exp(-(d @ d) / (2 * ns**2))

    mass = np.zeros(T)
    for t in range(T):
        for dy, dx in offsets:
            u = int(grid.neighbour(np.array([t]), dy, dx)[0])
            if u >= 0:
                mass[u] += weight(t, u, dy, dx)
    expected = []
    for dy, dx in offsets:
        for i, o in enumerate(obs):
            t, p = int(o % T), int(o // T)
            u = int(grid.neighbour(np.array([t]), dy, dx)[0])
            if u >= 0:
                expected.append((p * T + u, i, weight(t, u, dy, dx) / mass[u]))
    to, src, w = SpreadKernel(grid, sigma, normals, ns)(obs, T)
    assert to.tolist() == [e[0] for e in expected] and src.tolist() == [e[1] for e in expected]
    np.testing.assert_allclose(w, [e[2] for e in expected], rtol=1e-12)


def test_normal_aware_smoothing_does_not_gather_across_a_fold():
    """A field constant on each side of a 90 degree fold: the plain Gaussian mixes the sides in the columns next to
    the fold, the normal-aware kernel keeps each side's value; on one side alone both are the same Gaussian."""
    s = fold_surface(12, 24)
    floor = s.normals[:, 2] > 0.5
    values = torch.where(floor, 1.0, 3.0).to(torch.float64)[None, :, None].expand(2, -1, 3).clone()
    plain = smooth_on_grid(values, s.texel_index, s.grid_shape, 1.0)
    aware = smooth_on_grid(values, s.texel_index, s.grid_shape, 1.0, s.normals, 0.1)
    torch.testing.assert_close(aware, values, rtol=0, atol=1e-12)
    col = s.texel_index % s.grid_shape[1]
    next_to_fold = (col == 11) | (col == 12)
    assert (plain[0, next_to_fold, 0] - values[0, next_to_fold, 0]).abs().min() > 0.1
    # a smooth field on one plate: the normal factor is 1 there, so the result is the normalised Gaussian
    ramp = (s.positions[:, 1:2] * 0.1 + 2.0).expand(-1, 3)[None]
    on_floor = lambda x: x[:, floor & (col < 8)]
    torch.testing.assert_close(
        on_floor(smooth_on_grid(ramp, s.texel_index, s.grid_shape, 1.0, s.normals, 0.1)),
        on_floor(smooth_on_grid(ramp, s.texel_index, s.grid_shape, 1.0)),
        rtol=1e-10,
        atol=1e-12,
    )


def test_spreading_keeps_a_constant_field_and_does_not_cross_the_fold():
    """One unit entry per texel spread with the normalised kernel: every texel receives exactly 1 (interior and
    border alike); with the normal test nothing crosses the fold; copies stay with their light."""
    s = fold_surface(10, 20)
    T = s.num_texels
    for normals, ns in ((None, 0.0), (s.normals, 0.1)):
        obs = np.concatenate([np.arange(T), T + np.arange(T)])  # lights 0 and 1
        to, src, w = spread_on_grid(obs, T, s.neighbours, 1.0, normals, ns)
        received = np.bincount(to, weights=w, minlength=2 * T)
        np.testing.assert_allclose(received, 1.0, rtol=1e-12)
        assert ((to // T) == (obs[src] // T)).all()
    floor = (s.normals[:, 2] > 0.5).numpy()
    to, src, w = spread_on_grid(np.flatnonzero(floor), T, s.neighbours, 1.0, s.normals, 0.1)
    assert floor[to[w > 1e-12]].all()
    to, src, w = spread_on_grid(np.flatnonzero(floor), T, s.neighbours, 1.0)
    assert not floor[to[w > 1e-3]].all()  # the plain kernel does cross
