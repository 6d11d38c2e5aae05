"""Randomised QMC points: uniform like independent ones, stratified within a group."""

import numpy as np
import pytest
from scipy import stats

from torchrefl.core.rqmc import grouped_points, sobol_base, toroidal_shift


def test_points_are_uniform_and_grouped_by_shift():
    rng = np.random.default_rng(0)
    base = sobol_base(100, 3, rng)  # not a power of two: cut from 128
    shifts = rng.random((500, 3))
    u = toroidal_shift(base, shifts)
    assert u.shape == (50_000, 3) and (u >= 0).all() and (u < 1).all()
    for d in range(3):  # every coordinate uniform over all groups
        assert stats.kstest(u[:, d], "uniform").pvalue > 1e-3
    # rows g * n .. g * n + n - 1 are the base moved by shift g
    g = 7
    assert np.allclose(u[g * 100 : (g + 1) * 100], np.mod(base + shifts[g], 1.0))


def test_a_group_integrates_a_smooth_function_far_better_than_independent_points():
    f = lambda u: np.exp(u[:, 0]) * np.cos(u[:, 1]) * (1 + u[:, 2] ** 2)
    exact = (np.e - 1) * np.sin(1.0) * (4 / 3)
    n, groups = 256, 400
    rng = np.random.default_rng(1)
    q = f(toroidal_shift(sobol_base(n, 3, rng), rng.random((groups, 3)))).reshape(groups, n).mean(1)
    iid = f(rng.random((groups * n, 3))).reshape(groups, n).mean(1)
    assert abs(q.mean() - exact) < 4 * q.std() / np.sqrt(groups)  # unbiased
    assert q.std() < 0.2 * iid.std()  # stratified


def test_one_point_and_bad_counts():
    rng = np.random.default_rng(2)
    assert sobol_base(1, 2, rng).shape == (1, 2)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="n must be an integer >= 1"):
            sobol_base(bad, 2, rng)


def test_grouped_points_one_set_per_group():
    # singletons: one Sobol set, a shift per member (toroidal_shift)
    a = grouped_points(16, np.arange(5), np.random.default_rng(3), 3)
    rng = np.random.default_rng(3)
    assert np.array_equal(a, toroidal_shift(sobol_base(16, 3, rng), rng.random((5, 3))))
    # groups: the k-th member of a group takes the k-th block of one set, moved by the group's shift
    groups = np.array([4, 4, 4, 7, 9, 9])
    u = grouped_points(16, groups, np.random.default_rng(4), 3)
    rng = np.random.default_rng(4)
    base, shifts = sobol_base(48, 3, rng), rng.random((3, 3))
    assert u.shape == (96, 3) and (u >= 0).all() and (u < 1).all()
    assert np.allclose(u[:48], np.mod(base + shifts[0], 1.0))  # group 4: all 48 points
    assert np.allclose(u[48:64], np.mod(base[:16] + shifts[1], 1.0))  # group 7: the first block
    assert np.allclose(u[80:96], np.mod(base[16:32] + shifts[2], 1.0))  # group 9's second member
    assert grouped_points(8, np.zeros(0), rng, 2).shape == (0, 2)
