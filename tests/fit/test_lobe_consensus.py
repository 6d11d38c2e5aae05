"""Measured lobes against their measured neighbours (torchrefl.fit.lobe_consensus): an outlier of the lobe map whose
observations the neighbours' lobe explains as well takes it; one whose observations reject it, and every texel
within OUTLIER_RATIO of its neighbours, keep their own."""

import torch
from conftest import dome_scene, point_light_observations

from torchrefl.core.surface import Surface
from torchrefl.fit.lobe_consensus import OUTLIER_RATIO, agree_with_neighbours, neighbour_median
from torchrefl.fit.profile_search import profiled_fit
from torchrefl.transport.local import local_terms, predict

H = W = 8
T = H * W


def grid_surface() -> Surface:
    up = torch.zeros(T, 3, dtype=torch.float64)
    up[:, 2] = 1.0
    return Surface((H, W), torch.arange(T), torch.zeros(T, 3, dtype=torch.float64), up, torch.ones(T).double())


def scene(sigma: torch.Tensor, ps: torch.Tensor, noise: float = 0.003):
    """Texels on the dome (one per grid cell), Pd 0.5, the given lobes; noisy images and the profile of their fit."""
    nrm, pos, lights, cam = dome_scene(T=T, seed=7)
    obs = point_light_observations(nrm, pos, lights, cam, intensity=2.0e4)
    terms = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs)
    pd = torch.full((T, 3), 0.5, dtype=torch.float64)
    g = torch.Generator().manual_seed(8)
    intensity = predict(terms, pd, ps, sigma) + noise * torch.randn(obs.valid.shape + (3,), generator=g).double()
    return profiled_fit(terms, intensity, obs.valid), pd


def test_the_neighbour_median_counts_only_measured_texels():
    values = torch.full((T,), 0.2, dtype=torch.float64)
    measured = torch.ones(T, dtype=torch.bool)
    unmeasured = torch.arange(T) % 3 != 0  # two thirds of every window: counted, they would move every median
    values[unmeasured], measured[unmeasured] = 50.0, False
    med = neighbour_median(grid_surface(), values, measured, 5)
    assert torch.isnan(med[unmeasured]).all()
    assert torch.allclose(med[measured], torch.full((int(measured.sum()),), 0.2, dtype=torch.float64))


def test_the_tolerance_is_the_neighbours_median_error():
    """With the errors given: an outlier takes its neighbours' lobe where its error grows by at most the window median
    of the measured errors (1.0 here), not where it grows by more; texels at their neighbours' median are left."""
    sigma = torch.full((T,), 0.2, dtype=torch.float64)
    sigma[27] = 0.45
    error = torch.ones(T, dtype=torch.float64)
    for growth, taken in ((0.9, True), (1.1, False)):

        def evaluate(s, growth=growth):
            grown = torch.where(torch.isclose(s, torch.tensor(0.2, dtype=torch.float64)), error + growth, error)
            return torch.zeros(T, 3, dtype=torch.float64), torch.zeros(T, 3, dtype=torch.float64), grown

        adopt, _ = agree_with_neighbours(grid_surface(), sigma, error, torch.ones(T, dtype=torch.bool), 5, evaluate)
        assert adopt.nonzero().flatten().tolist() == ([27] if taken else [])


def test_an_outlier_the_neighbours_lobe_explains_takes_it_and_its_pd_comes_right():
    sigma = torch.full((T,), 0.15, dtype=torch.float64)
    ps = torch.full((T, 3), 0.3, dtype=torch.float64)
    profile, pd_true = scene(sigma, ps)
    start = sigma.clone()
    start[27] = 0.45  # a search left in the wrong basin
    _, _, err = profile(start)
    adopt, (pd, ps_c, sg, _) = agree_with_neighbours(
        grid_surface(), start, err, torch.ones(T, dtype=torch.bool), 5, profile
    )
    assert adopt.nonzero().flatten().tolist() == [27]
    assert abs(float(sg[27]) - 0.15) < 1e-9
    assert (pd[27] - pd_true[27]).abs().max() < 0.01
    assert (ps_c[27] - 0.3).abs().max() < 0.02


def test_a_texel_whose_observations_reject_the_neighbours_lobe_keeps_its_own():
    sigma = torch.full((T,), 0.1, dtype=torch.float64)
    ps = torch.full((T, 3), 0.3, dtype=torch.float64)
    sigma[27], ps[27] = 0.3, 0.45  # another material, measured: its highlights say so
    profile, _ = scene(sigma, ps)
    _, _, err = profile(sigma)
    adopt, _ = agree_with_neighbours(grid_surface(), sigma, err, torch.ones(T, dtype=torch.bool), 5, profile)
    assert not adopt.any()


def test_texels_within_the_ratio_and_at_a_straight_border_keep_their_lobes():
    sigma = torch.full((T,), 0.1, dtype=torch.float64)
    sigma.view(H, W)[:, W // 2 :] = 0.3  # two materials side by side
    sigma.view(H, W)[2, 1] = 0.1 * OUTLIER_RATIO * 0.95  # within the ratio of its neighbours
    ps = torch.full((T, 3), 0.3, dtype=torch.float64)
    profile, _ = scene(sigma, ps)
    _, _, err = profile(sigma)
    adopt, _ = agree_with_neighbours(grid_surface(), sigma, err * 0 + 1.0, torch.ones(T, dtype=torch.bool), 5, profile)
    assert not adopt.any()  # even with every error equal (no evidence either way): none is an outlier
