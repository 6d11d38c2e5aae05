"""Interpolation of undetermined texels (W x W window, then the median of the determined texels)."""

import numpy as np
import torch

from torchrefl.core.texel_grid import TexelGrid
from torchrefl.fit.interpolate import fill_undetermined as fill_texels


def fill_undetermined(grid, known, inside, **options):
    """fill_texels on every cell of the (H, W, C) grid as one texel of a plain TexelGrid, back on the grid."""
    H, W, C = grid.shape
    out, how = fill_texels(
        TexelGrid(np.arange(H * W), (H, W)), grid.reshape(H * W, C), known.reshape(-1), inside.reshape(-1), **options
    )
    return out.reshape(H, W, C), how.reshape(H, W)


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


def test_a_large_gap_takes_the_median_of_the_determined_texels_not_a_stray_row_value():
    """Beyond the window passes a texel takes the median of every determined texel: a row that holds one stray
    determined value (the fold's lower plate) does not carry it across the row (the seed's row interpolation did)."""
    grid = torch.full((12, 40, 2), 0.3, dtype=torch.float64)
    known = torch.zeros(12, 40, dtype=torch.bool)
    known[:3] = True  # a measured band: every value 0.3
    known[9, 20] = True
    grid[9, 20] = torch.tensor([0.02, 0.5], dtype=torch.float64)  # one stray texel far from it
    grid[~known] = float("nan")  # undetermined values are never read
    inside = torch.ones(12, 40, dtype=torch.bool)
    out, how = fill_undetermined(grid, known, inside, window=3, max_passes=1)
    assert torch.isfinite(out).all()
    assert set(torch.unique(how).tolist()) == {1, 2, 4}
    assert (how[3] == 2).all() and (how[6, :10] == 4).all()  # one pass of a 3 x 3 window reaches one row
    assert torch.allclose(out[6, :10], torch.tensor([0.3, 0.3], dtype=torch.float64))
    assert torch.allclose(out[9, 0], torch.tensor([0.3, 0.3], dtype=torch.float64))  # not the stray row's value


def test_one_extreme_determined_texel_does_not_spread_into_its_neighbours():
    """A measured texel with an extreme lobe (Ps at its bound, sigma narrow) beside ordinary ones: the texels filled
    from that window take the ordinary lobe (the window's median), not a mix with the extreme one (its mean)."""
    grid = torch.zeros(9, 9, 2, dtype=torch.float64)
    grid[..., 0], grid[..., 1] = 0.3, 0.15
    known = torch.zeros(9, 9, dtype=torch.bool)
    known[:, :3] = True  # a measured band on the left, the rest to fill
    grid[4, 2] = torch.tensor([4.0, 0.011], dtype=torch.float64)
    inside = torch.ones(9, 9, dtype=torch.bool)
    out, how = fill_undetermined(grid, known, inside, window=5)
    assert (how[:, 3:5] == 2).all()
    torch.testing.assert_close(out[:, 3:5], grid[:1, :1].expand(9, 2, 2), rtol=0, atol=1e-12)


def test_on_an_atlas_the_window_reaches_across_seams_and_not_across_the_gutter():
    """A cube whose face 0 is undetermined: with one pass of a 3 x 3 window its border texels take the neighbouring
    faces' value across the cube's edges (window code 2), its interior the median (code 4). On the plain grid of the
    same atlas the charts' gutter cuts face 0 off: its texels all take the median."""
    from conftest import atlas_cube

    s = atlas_cube(side=8, gap=1).surface
    chart = torch.from_numpy(s.extras["chart"])
    values = torch.where(chart == 0, 99.0, 0.25).double()[:, None]
    known = chart != 0
    inside = torch.ones(s.num_texels, dtype=torch.bool)
    out, how = fill_texels(s.neighbours, values, known, inside, window=3, max_passes=1)
    rows, cols = s.neighbours.rows, s.neighbours.cols
    face = chart == 0
    r, c = torch.from_numpy(rows), torch.from_numpy(cols)
    border = face & ((r == r[face].min()) | (r == r[face].max()) | (c == c[face].min()) | (c == c[face].max()))
    assert (how[border] == 2).all() and (how[face & ~border] == 4).all()
    assert torch.all(out[face] == 0.25)
    _, plain = fill_texels(
        TexelGrid(s.texel_index.numpy(), s.grid_shape), values, known, inside, window=3, max_passes=1
    )
    assert (plain[face] == 4).all()
