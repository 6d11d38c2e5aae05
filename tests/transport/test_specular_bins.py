"""The specular entries' theta_h bins and their merge: what a merged entry holds, and the per-light spread and
merge (cache_build.build_cache) against the all-at-once one."""

import numpy as np
import pytest
import torch
from conftest import fold_surface

from torchrefl.core.brdf import specular_lobe
from torchrefl.transport.photon_density import spread_on_grid
from torchrefl.transport.specular_bins import merge_entries, sorted_inverse, spread_and_merge, theta_bins


def test_entries_of_one_bin_merge_into_their_sum_at_the_weighted_mean_angle():
    T = 4
    sigma = np.array([0.1, 0.1, 0.4, 0.1])
    # observation 1 (texel 1): two entries in one bin, one in the next; observation T + 2 (rough texel 2): the
    # same angles share one wider bin; observation 3: alone
    obs = np.array([1, 1, 1, T + 2, T + 2, T + 2, 3])
    theta = np.array([0.1000, 0.1010, 0.1300, 0.1000, 0.1010, 0.1300, 0.2])
    w = np.arange(1.0, 8.0)[None].repeat(3, 0)
    e_obs, th, ws = merge_entries(obs, theta, w, sigma, T)
    assert e_obs.tolist() == [1, 1, 3, T + 2]
    np.testing.assert_allclose(ws[:, 0], [1 + 2, 3, 7, 4 + 5 + 6])
    np.testing.assert_allclose(th[0], (0.1 * 1 + 0.101 * 2) / 3)
    assert theta_bins(np.array([0.1, 0.13]), np.array([0.1, 0.1])).tolist() == [4, 5]  # 0.025 wide
    assert theta_bins(np.array([0.1, 0.13]), np.array([0.4, 0.4])).tolist() == [1, 1]  # 0.1 wide


def test_merging_keeps_the_lobe_sum_within_half_a_percent():
    """sum_k w_k D(theta_k; sigma) over one texel's entries, before and after the merge, at its roughness."""
    rng = np.random.default_rng(0)
    for sigma_t in (0.02, 0.1, 0.4):
        theta = rng.uniform(0.0, 3 * sigma_t, 5000)
        w = rng.uniform(0.0, 1.0, (3, 5000))
        e_obs, th, ws = merge_entries(np.zeros(5000, dtype=np.int64), theta, w, np.array([sigma_t]), 1)
        D = lambda x: specular_lobe("torrance_sparrow", torch.from_numpy(x), torch.tensor(sigma_t)).numpy()
        before = (w[0] * D(theta)).sum()
        after = (ws[:, 0] * D(th)).sum()
        assert abs(after / before - 1) < 5e-3, sigma_t


def test_specular_entries_are_spread_and_merged_per_light_as_all_at_once():
    """build_cache spreads and merges the specular entries one light at a time (to bound memory): the result is
    the merge of all entries spread at once, in its order, for lights in any order and a light with no entry."""
    s = fold_surface(10, 20)
    T = s.num_texels
    rng = np.random.default_rng(3)
    M = 4000
    e_obs = rng.choice([0, 1, 3], M) * T + rng.integers(0, T, M)  # lights 0, 1 and 3 (none for light 2), shuffled
    theta_h = rng.uniform(0.0, 0.6, M)
    weight = rng.uniform(0.0, 1.0, (3, M))
    sigma = rng.uniform(0.05, 0.4, T)
    spread = lambda obs: spread_on_grid(obs, T, s.neighbours, 1.5, s.normals, 0.1)
    (obs, th, w), count = spread_and_merge(e_obs, theta_h, weight, spread, sigma, T, 0.004, 0.25)
    to, src, k = spread(e_obs)
    ref = merge_entries(to, theta_h[src], weight[:, src] * k, sigma, T, 0.004, 0.25)
    assert count == to.size
    np.testing.assert_array_equal(obs, ref[0])
    np.testing.assert_allclose(th, ref[1], rtol=1e-12)
    np.testing.assert_allclose(w, ref[2], rtol=1e-12)
    (obs, th, w), count = spread_and_merge(e_obs, theta_h, weight, None, sigma, T, 0.004, 0.25)
    ref = merge_entries(e_obs, theta_h, weight, sigma, T, 0.004, 0.25)
    assert count == M
    np.testing.assert_array_equal(obs, ref[0])
    np.testing.assert_allclose(w, ref[2], rtol=1e-12)


@pytest.mark.parametrize("runs", [None, 2])
@pytest.mark.parametrize("spread", [3, 400_000, 2**60])
def test_sorted_inverse_is_the_rank_among_the_sorted_distinct_pairs(spread, runs):
    """Dense slots (few observations) and the sort (observations spread wide; in any order, or in a few sorted runs
    as the cache average has them) give the rank of (obs, bin) among the distinct pairs, bins below 0 and past the last
    included (a merged entry's mean angle can leave [0, pi / 2])."""
    rng = np.random.default_rng(spread)
    obs = 1000 + rng.integers(0, spread, 5000)
    bins = rng.integers(-3, 40, 5000)
    bins[:3] = [500, -700, 393]
    if runs is not None:
        parts = np.array_split(np.arange(obs.size), runs)
        order = np.concatenate([p[np.lexsort((bins[p], obs[p]))] for p in parts])
        obs, bins = obs[order], bins[order]
    pairs = sorted(set(zip(obs.tolist(), bins.tolist())))
    rank = {pair: i for i, pair in enumerate(pairs)}
    expected = [rank[pair] for pair in zip(obs.tolist(), bins.tolist())]
    np.testing.assert_array_equal(sorted_inverse(obs, bins), expected)
