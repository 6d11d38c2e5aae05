"""Misfit texels (torchrefl.fit.misfit): texels whose residual stands far out of the object's are found; noise
alone, however large, flags none; held-out and unestimated texels are not judged."""

import numpy as np
import torch

from torchrefl.core.texel_grid import TexelGrid
from torchrefl.fit.misfit import misfit_texels, near_edge


def images(P=12, T=500, noise_dn=0.5, seed=0):
    gen = torch.Generator().manual_seed(seed)
    truth = 0.2 + 0.6 * torch.rand(P, T, 3, generator=gen, dtype=torch.float64)
    observed = truth + noise_dn / 255.0 * torch.randn(P, T, 3, generator=gen, dtype=torch.float64)
    return truth, observed


def test_texels_the_model_cannot_explain_are_found_and_noise_alone_flags_none():
    for noise in (0.0, 0.3, 3.0):  # a noise-free fit, sensor noise, heavy noise
        predicted, observed = images(noise_dn=noise)
        P, T, _ = observed.shape
        fit, estimated = torch.ones(P, T, dtype=torch.bool), torch.ones(T, dtype=torch.bool)
        assert not misfit_texels(predicted, observed, fit, estimated).any(), noise
        bad = torch.tensor([3, 77, 401])
        observed[:6, bad] += 12.0 / 255.0  # half of their images carry light the model has no term for
        found = misfit_texels(predicted, observed, fit, estimated)
        assert set(torch.nonzero(found).flatten().tolist()) == set(bad.tolist()), noise


def test_only_fitted_observations_of_estimated_texels_are_judged():
    predicted, observed = images()
    P, T, _ = observed.shape
    observed[:, 10] += 20.0 / 255.0
    fit = torch.ones(P, T, dtype=torch.bool)
    estimated = torch.ones(T, dtype=torch.bool)
    estimated[10] = False
    assert not misfit_texels(predicted, observed, fit, estimated).any()
    estimated[10] = True
    fit[:, 10] = False  # only held-out observations: nothing to judge it by
    assert not misfit_texels(predicted, observed, fit, estimated).any()


def test_only_texels_next_to_an_edge_or_untrusted_geometry_may_be_misfits():
    """A 10 x 10 grid with one untrusted texel at (5, 5) and the grid's own border: texels within two of either are
    candidates; the interior away from both never is (a misfit there is the model's, and must stay in the metrics)."""
    H, W = 10, 10
    index = torch.arange(H * W)
    trusted = torch.ones(H * W, dtype=torch.bool)
    trusted[5 * W + 5] = False
    near = near_edge(TexelGrid(index.numpy(), (H, W)), trusted).view(H, W)
    assert near[0].all() and near[:, 0].all() and near[3:8, 3:8].all()
    assert not near[2, 2] and not near[2, 7] and not near[7, 2]
    off_surface = near_edge(TexelGrid(index[index != 0].numpy(), (H, W)), torch.ones(H * W - 1, dtype=torch.bool))
    assert off_surface[:2].all()  # (0, 1), (0, 2): next to the missing texel (0, 0)


def test_near_an_edge_on_an_atlas_means_near_the_surface_s_edge_not_a_chart_s():
    """A closed cube on its atlas has no edge: no texel is near one although every chart has a border next to the
    gutter (the plain grid of the same texels flags those). One untrusted texel at a chart's border flags the texels
    across the seam too."""
    from conftest import atlas_cube

    s = atlas_cube(side=8).surface
    T = s.num_texels
    trusted = torch.ones(T, dtype=torch.bool)
    assert not near_edge(s.neighbours, trusted).any()
    assert near_edge(TexelGrid(s.texel_index.numpy(), s.grid_shape), trusted).sum() > T // 2
    chart = s.extras["chart"]
    t = int(np.flatnonzero(s.neighbours.chart != s.neighbours.chart[s.neighbours.step[:, 0]])[0])  # seam on its right
    across = int(s.neighbours.step[t, 0])
    trusted[t] = False
    near = near_edge(s.neighbours, trusted)
    assert near[across] and chart[across] != chart[t]
    assert not near[
        np.linalg.norm(s.positions.numpy() - s.positions.numpy()[t], axis=1) > 4.0
    ].any()  # radius 2: < 3 mm
