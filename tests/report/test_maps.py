import numpy as np
from PIL import Image

from torchrefl.report.maps import COVERAGE_COLOURS, write_light_maps, write_parameter_maps

H, W = 40, 50


def read(path):
    with Image.open(path) as im:
        assert im.mode == "RGBA", path
        return np.asarray(im)


def written(tmp_path):
    mask = np.ones((H, W), dtype=bool)
    mask[10:20, 15:30] = False
    pd = np.full((H, W, 3), 0.5)
    ps = np.random.default_rng(0).uniform(0.1, 0.2, (H, W, 3))
    ps[0, 0] = ps[39, 49] = 20.0  # two texels at 100x
    sigma = np.full((H, W), 0.2)
    coverage = np.where(mask, 2, 0)
    for a in (pd, ps, sigma):
        a[~mask] = 0.0
    scales = write_parameter_maps(tmp_path, mask, pd, ps, sigma, coverage, sigma_max=0.6)
    return mask, scales


def test_texels_without_an_estimate_are_transparent(tmp_path):
    mask, _ = written(tmp_path)
    for name in ("pd", "ps", "sigma", "coverage"):
        img = read(tmp_path / f"{name}.png")
        assert (img[..., 3][~mask] == 0).all() and (img[..., 3][mask] == 255).all(), name
    cov = read(tmp_path / "coverage.png")
    assert (cov[mask][:, :3] == COVERAGE_COLOURS[2]).all()


def test_pd_is_srgb_encoded_and_outliers_do_not_set_the_ps_white(tmp_path):
    mask, scales = written(tmp_path)
    assert (read(tmp_path / "pd.png")[mask][:, :3] == 188).all()  # linear 0.5 is sRGB 0.7354
    assert 0.15 < scales["ps_white"] < 0.21
    ps = read(tmp_path / "ps.png")[mask][:, :3]
    assert (ps == 255).mean() < 0.05 and np.median(ps) > 100
    # a constant sigma is one grey, shown white as its own 99th percentile
    assert (read(tmp_path / "sigma.png")[mask][:, :3] == 255).all()
    assert abs(scales["sigma_white"] - 0.2) < 1e-3


def test_light_maps_leave_invalid_texels_transparent_not_zero_difference(tmp_path):
    shown = np.zeros((H, W), dtype=bool)
    shown[5:30] = True
    observed = np.full((H, W, 3), 0.25)
    write_light_maps(tmp_path, "light_000", observed, observed, shown)
    diff = read(tmp_path / "light_000_diff.png")
    assert (diff[shown] == (128, 128, 128, 255)).all()
    assert (diff[~shown][:, 3] == 0).all()
    assert (read(tmp_path / "light_000_observed.png")[~shown][:, 3] == 0).all()
