"""Texels without a fitted observation emit with the nearest fitted texel's parameters."""

import numpy as np
import pytest
import torch
from conftest import fold_surface, point_light_observations

from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.fit.emitter_fill import nearest_fitted
from torchrefl.fit.pipeline import level_inputs
from torchrefl.transport.levels.photon import PhotonLevel
from torchrefl.transport.levels.radiosity import RadiosityLevel


def test_each_texel_maps_to_the_nearest_fitted_texel():
    """Against a brute-force search over all pairs; fitted texels map to themselves."""
    rng = np.random.default_rng(3)
    pos = torch.from_numpy(rng.normal(size=(300, 3)))
    fitted = torch.from_numpy(rng.random(300) < 0.4)
    src = nearest_fitted(pos, fitted)
    d = torch.cdist(pos, pos[fitted])
    expect = torch.nonzero(fitted).squeeze(1)[d.argmin(1)]
    expect[fitted] = torch.nonzero(fitted).squeeze(1)
    assert torch.equal(src, expect)


def test_all_or_no_fitted_texels_leave_every_texel_its_own_and_bad_shapes_raise():
    pos = torch.zeros(5, 3)
    assert torch.equal(nearest_fitted(pos, torch.ones(5, dtype=torch.bool)), torch.arange(5))
    assert torch.equal(nearest_fitted(pos, torch.zeros(5, dtype=torch.bool)), torch.arange(5))
    with pytest.raises(ValueError, match="5 positions but 4 fitted flags"):
        nearest_fitted(pos, torch.ones(4, dtype=torch.bool))


def fold_setup(hemisphere_samples=256, **photon):
    s = fold_surface(8, 16)
    obs = point_light_observations(
        s.normals, s.positions, torch.tensor([[-40.0, 0.0, 25.0]]), torch.tensor([-150.0, 0.0, 150.0])
    )
    cfg = Config()
    cfg.reflectance.brdf = "torrance_sparrow"
    cfg.radiosity.hemisphere_samples = hemisphere_samples
    for k, v in photon.items():
        setattr(cfg.photon, k, v)
    inputs, _ = level_inputs(cfg, Capture(s, obs), lambda *a: None)
    radiosity = RadiosityLevel(inputs)
    radiosity.prepare()
    # "unfitted": the wall's outer rim and two fold-line columns (as silhouette and crease texels would be)
    grid = torch.zeros(8, 16, dtype=torch.bool)
    grid[:, 14:] = True
    grid[:, 7:9] = True
    fitted = ~grid.reshape(-1)
    return cfg, s, obs, radiosity, fitted


def test_filled_emitters_give_back_the_interreflection_black_ones_lose():
    """Uniform Pd 0.7: with the unfitted texels' Pd at 0 the fitted texels' indirect light drops by several per
    cent; filled from the nearest fitted texel it is the all-known indirect light exactly (uniform Pd)."""
    _, s, _, radiosity, fitted = fold_setup()
    T = s.num_texels
    truth = torch.full((T, 3), 0.7, dtype=torch.float64)
    black = truth * fitted[:, None]
    H_true = radiosity.indirect(truth)[:, fitted]
    H_black = radiosity.indirect(black)[:, fitted]
    radiosity.use_emitters(nearest_fitted(s.positions, fitted))
    H_fill = radiosity.indirect(black)[:, fitted]
    lost = float(1 - H_black.sum() / H_true.sum())
    assert lost > 0.05, lost
    torch.testing.assert_close(H_fill, H_true)


def test_the_filled_indirect_light_has_float64_gradients_that_reach_the_source_texels():
    _, s, _, radiosity, fitted = fold_setup(hemisphere_samples=16)
    radiosity.use_emitters(nearest_fitted(s.positions, fitted))
    filled = radiosity.indirect
    rng = np.random.default_rng(0)
    pd = torch.tensor(rng.uniform(0.2, 0.9, (s.num_texels, 3)), requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: filled(x)[:, :, 0].sum(0), (pd,), eps=1e-6, atol=1e-6)
    (g,) = torch.autograd.grad(filled(pd).sum(), pd)
    assert bool((g[~fitted] == 0).all()) and bool((g[fitted].abs().sum(1) > 0).any())


def test_the_photon_level_scatters_with_the_filled_parameters():
    """A PhotonLevel given the emitter source traces with Pd, Ps, sigma taken from the nearest fitted texel: its
    cache equals that of a level without it traced with the filled tensors (same seed), and differs from the
    cache of the black tensors."""
    cfg, s, obs, radiosity, fitted = fold_setup(photons_per_light=20_000, diffuse_paths="photons", specular_gather=0)
    T = s.num_texels
    src = nearest_fitted(s.positions, fitted)
    pd = torch.full((T, 3), 0.6, dtype=torch.float64) * fitted[:, None]
    ps, sigma = torch.full((T, 3), 0.3, dtype=torch.float64), torch.full((T,), 0.1, dtype=torch.float64)

    def make(source, prepare_first=False):
        level = PhotonLevel(radiosity.inputs, radiosity)
        if prepare_first:  # as fit_capture does for fit.model photon: prepared before the start's fitted texels
            level.prepare()
        if source is not None:
            level.use_emitters(source)
        if not prepare_first:
            level.prepare()
        return level.refresher

    with_fill = make(src).cache(pd, ps, sigma, refresh=0)
    pre_filled = make(None).cache(pd[src], ps[src], sigma[src], refresh=0)
    black = make(None).cache(pd, ps, sigma, refresh=0)
    torch.testing.assert_close(with_fill.irradiance, pre_filled.irradiance)
    filled_later = make(src, prepare_first=True).cache(pd, ps, sigma, refresh=0)
    torch.testing.assert_close(filled_later.irradiance, pre_filled.irradiance)
    assert float(with_fill.irradiance[:, fitted].sum()) > 1.02 * float(black.irradiance[:, fitted].sum())


def test_the_fit_logs_the_filled_texels_at_the_interreflection_levels_only():
    """End to end on a small fold: at the radiosity level the log names the texels filled (the wall's rim is never
    lit here); at the local level nothing is filled (no interreflection)."""
    from torchrefl.core.progress import Stages
    from torchrefl.fit.pipeline import fit_capture

    s = fold_surface(6, 12, dtype=torch.float32)
    obs = point_light_observations(
        s.normals,
        s.positions,
        torch.tensor([[-40.0, 0.0, 25.0], [-30.0, 10.0, 30.0]]),
        torch.tensor([-150.0, 0.0, 150.0]),
        dtype=torch.float32,
    )
    col = s.texel_index % 12
    obs.valid[:, col >= 10] = False  # two wall columns without a fitted observation
    lines = {}
    for model in ("radiosity", "local"):
        cfg = Config()
        cfg.fit.model = model
        cfg.fit.iterations = 2
        cfg.radiosity.hemisphere_samples = 32
        cfg.output.progress = False
        log = []
        fit_capture(cfg, Capture(s, obs), Stages(), log.append, torch.device("cpu"))
        lines[model] = [l for l in log if "nearest fitted texel" in l]
    assert len(lines["radiosity"]) == 1 and lines["radiosity"][0].startswith("interreflection: 12 texels")
    assert lines["local"] == []
