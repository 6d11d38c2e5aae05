import numpy as np
from matplotlib.colors import Normalize

from torchrefl.report.display import robust_range, srgb


def test_two_outliers_stay_outside_the_range():
    rng = np.random.default_rng(0)
    ps = rng.uniform(0.1, 0.3, size=(30, 40))
    ps[3, 4] = ps[20, 30] = 30.0
    r = robust_range(ps)
    assert 0.25 < r.vmax < 0.31 and 0.1 <= r.vmin < 0.15
    assert r.above and r.below and r.extend == "both"


def test_a_constant_map_is_one_colour_at_the_middle():
    for level in (0.3, 0.0, 1e4):
        values = np.full((10, 12), level) + np.random.default_rng(1).normal(0, 1e-12, (10, 12))
        r = robust_range(values)
        shown = Normalize(r.vmin, r.vmax)(values)
        np.testing.assert_allclose(shown, 0.5, atol=1e-3)
        assert r.extend == "neither"


def test_mask_and_physical_limits():
    values = np.array([[-5.0, 0.2, 0.4], [0.1, 0.3, 900.0]])
    mask = np.array([[False, True, True], [True, True, False]])
    r = robust_range(values, mask, percentiles=(0, 100))
    assert (r.vmin, r.vmax) == (0.1, 0.4)
    r = robust_range(values, None, percentiles=(0, 100), lower=0.0, upper=0.6)
    assert (r.vmin, r.vmax, r.below, r.above) == (0.0, 0.6, True, True)
    r = robust_range(values, np.zeros_like(mask), upper=0.6)
    assert (r.vmin, r.vmax) == (0.0, 0.6)
    assert robust_range(np.full(3, np.nan)).vmax == 1.0


def test_srgb_encoding():
    # the sRGB transfer function: 12.92 v below 0.0031308, 1.055 v^(1/2.4) - 0.055 above; clipped to [0, 1]
    out = srgb(np.array([[0.5, 0.002, 1.0], [-1.0, 2.0, 0.0]]))
    np.testing.assert_allclose(out, [[0.735357, 0.02584, 1.0], [0.0, 1.0, 0.0]], atol=1e-5)
    assert srgb(np.zeros((4, 5, 3))).shape == (4, 5, 3)
