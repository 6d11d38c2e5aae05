"""Randomised quasi-Monte Carlo points: one scrambled Sobol set shared by many groups, each group
moved by its own uniform toroidal shift (Cranley-Patterson rotation).

Every point of a shifted set is uniform on [0, 1)^d, so an estimator that averages a group's points is
unbiased exactly as with independent uniforms, and the groups' errors are independent given their
shifts; within a group the points are stratified, so for a smooth integrand the error falls faster
than 1/sqrt(n). grouped_points lets the members of a group (points whose estimates are averaged
afterwards, such as a texel's sub-samples) take consecutive blocks of one larger set, so the group's mean is
stratified over all of its points. Used by the renderer's first bounce (torchrefl.synthetic.path_tracer), the specular
gather's directions (torchrefl.transport.specular_gather) and the form factors' hemisphere rays
(torchrefl.transport.form_factors).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import qmc


def sobol_base(n: int, dim: int, rng: np.random.Generator) -> np.ndarray:
    """(n, dim) float64: the first n points of a scrambled Sobol set drawn with rng (n = 1: one uniform
    point). The set is generated to the next power of two and cut, so every point stays uniform."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if n == 1:
        return rng.random((1, dim))
    return qmc.Sobol(dim, scramble=True, seed=rng).random_base2(int(math.ceil(math.log2(n))))[:n]


def toroidal_shift(base: np.ndarray, shifts: np.ndarray) -> np.ndarray:
    """(G * n, dim): the base set (n, dim) moved by each group's shift (G, dim), modulo 1, group by group
    (rows g * n .. g * n + n - 1 belong to group g)."""
    n = len(base)
    return np.mod(np.tile(base, (len(shifts), 1)) + np.repeat(shifts, n, axis=0), 1.0)


def grouped_points(n: int, groups: np.ndarray, rng: np.random.Generator, dim: int) -> np.ndarray:
    """(M * n, dim): n points for each of M members, member by member; groups (M,) labels the members in
    contiguous runs. The members of a group share one scrambled Sobol set of n times the largest group's
    size points, moved by a uniform shift per group; the k-th member of a group takes the set's k-th block of
    n points. Every point is uniform, so each member's estimate stays unbiased, and a group's mean is
    stratified over all its points. Groups of one member each are toroidal_shift(sobol_base(n, dim, rng),
    rng.random((M, dim)))."""
    groups = np.asarray(groups)
    M = len(groups)
    if M == 0:
        return np.zeros((0, dim))
    new = np.r_[True, groups[1:] != groups[:-1]]
    gid = np.cumsum(new) - 1  # group of each member, 0..G-1
    first = np.flatnonzero(new)
    rank = np.arange(M) - first[gid]  # position within its group
    size = int(rank.max()) + 1
    if size == 1:
        return toroidal_shift(sobol_base(n, dim, rng), rng.random((M, dim)))
    base = sobol_base(n * size, dim, rng)
    shifts = rng.random((len(first), dim))
    rows = (rank[:, None] * n + np.arange(n)[None, :]).ravel()
    return np.mod(base[rows] + np.repeat(shifts[gid], n, axis=0), 1.0)
