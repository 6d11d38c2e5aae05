"""Interpolation of undetermined texels (W x W window, then rows, then median)."""

import torch

from torchrefl.fit.interpolate import fill_undetermined


def test_holes_in_a_linear_ramp_are_filled_by_neighbours():
    H, W = 20, 30
    yy, xx = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    grid = torch.stack([xx * 0.01 + 0.2, yy * 0.0 + 0.5], -1)
    known = torch.ones(H, W, dtype=torch.bool)
    known[5:7, 10:12] = False  # a 2 x 2 hole: the symmetric window mean is exact on a ramp
    inside = torch.ones(H, W, dtype=torch.bool)
    damaged = grid.clone()
    damaged[~known] = 99.0  # undetermined values must not leak
    out, how = fill_undetermined(damaged, known, inside, window=5)
    torch.testing.assert_close(out[~known], grid[~known], atol=2e-3, rtol=0)
    assert (how[~known] == 2).all() and (how[known] == 1).all()


def test_outside_texels_are_untouched_and_never_used():
    grid = torch.zeros(10, 10, 1, dtype=torch.float64)
    grid[:, :5] = 1.0
    known = torch.ones(10, 10, dtype=torch.bool)
    inside = torch.ones(10, 10, dtype=torch.bool)
    inside[:, 5:] = False  # right half is outside the object
    known[4, 4] = False
    out, how = fill_undetermined(grid, known, inside, window=3)
    assert abs(float(out[4, 4, 0]) - 1.0) < 1e-12  # only inside neighbours (all 1) are averaged
    assert (how[:, 5:] == 0).all()


def test_large_gap_falls_back_to_rows_then_median():
    grid = torch.rand(12, 40, 2, dtype=torch.float64)
    known = torch.zeros(12, 40, dtype=torch.bool)
    known[3, 0] = known[3, 39] = True
    grid[3, 0] = torch.tensor([0.0, 1.0], dtype=torch.float64)
    grid[3, 39] = torch.tensor([1.0, 1.0], dtype=torch.float64)
    inside = torch.ones(12, 40, dtype=torch.bool)
    out, how = fill_undetermined(grid, known, inside, window=3, max_passes=1)
    assert torch.isfinite(out).all()
    assert set(torch.unique(how).tolist()) <= {1, 2, 3, 4}
    assert (how[0] >= 2).all()
