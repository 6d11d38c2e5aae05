"""Refinement: LBFGS and Adam recover known parameters from noisy 8-bit observations; robust loss."""

import numpy as np
import pytest
import torch
from conftest import noisy_glossy_scene as noisy_scene

from torchrefl.core.observation_classes import classify
from torchrefl.core.params import TexelParams
from torchrefl.core.texel_grid import TexelGrid
from torchrefl.fit.closed_form import closed_form
from torchrefl.fit.refine import Objective, Prior, neighbour_pairs, refine, robust_loss
from torchrefl.transport.local import predict


def fit(obs, terms, optimizer, loss="huber", iterations=80, lr=0.05):
    cls = classify(terms.theta_h, obs.valid)
    cf = closed_form(terms, obs.intensity, cls, obs.valid, 3, 0.01, 0.6)
    ps0 = torch.where(cf.spec_determined[:, None], cf.ps, torch.full_like(cf.ps, 0.2))
    sg0 = torch.where(cf.spec_determined, cf.sigma, torch.full_like(cf.sigma, 0.15))
    params = TexelParams(cf.pd, ps0, sg0, 0.01, 0.6)
    obj = Objective(lambda a, b, c: predict(terms, a, b, c), obs.intensity, obs.valid, loss=loss, loss_scale_8bit=2.0)
    hist = refine(params, obj, optimizer, iterations, lr)
    return params, hist, cf


@pytest.mark.parametrize("optimizer", ["lbfgs", "adam"])
def test_refinement_recovers_truth(optimizer):
    obs, terms, (pd, ps, sigma) = noisy_scene()
    params, hist, cf = fit(obs, terms, optimizer, iterations=80 if optimizer == "lbfgs" else 300)
    assert hist[-1] < hist[0]
    epd, eps, esg = (x.detach() for x in params.values())
    assert torch.sqrt(((epd - pd) ** 2).mean()) < 0.01
    assert ((esg - sigma).abs() / sigma).median() < 0.05
    assert ((eps.mean(-1) - ps.mean(-1)).abs() / ps.mean(-1)).median() < 0.05


def test_robust_loss_resists_outliers():
    obs, terms, (pd, ps, sigma) = noisy_scene(outliers=400)
    errs = {}
    for loss in ("l2", "huber"):
        params, _, _ = fit(obs, terms, "lbfgs", loss=loss)
        errs[loss] = float((params.pd().detach() - pd).abs().max(-1).values.median())
    assert errs["huber"] < 0.5 * errs["l2"]


def test_robust_losses_agree_near_zero_and_grow_slower():
    r = torch.tensor([0.01, 10.0], dtype=torch.float64)
    l2 = robust_loss(r, "l2", 1.0)
    for kind in ("huber", "cauchy"):
        v = robust_loss(r, kind, 1.0)
        assert abs(float(v[0] - l2[0])) < 1e-6 and v[1] < l2[1]


def test_neighbour_pairs():
    idx = torch.tensor([0, 1, 3, 4, 8])  # 3 x 3 grid, texels 0,1,3,4,8 valid
    pairs = {tuple(p) for p in neighbour_pairs(TexelGrid(idx.numpy(), (3, 3))).tolist()}
    assert pairs == {(0, 1), (2, 3), (0, 2), (1, 3)}


def test_gradcheck_objective_with_priors_and_smoothness_float64():
    obs, terms, (pd, ps, sigma) = noisy_scene(T=6, seed=4)
    mask = torch.tensor([True, False, True, True, False, True])
    priors = [Prior(mask, ps * 1.2, sigma * 0.9, 0.7)]
    pairs = torch.tensor([[0, 1], [2, 3], [4, 5], [1, 2]])
    obj = Objective(
        lambda a, b, c: predict(terms, a, b, c),
        obs.intensity,
        obs.valid,
        priors=priors,
        smoothness=0.3,
        neighbours=pairs,
    )
    params = TexelParams(pd, ps, sigma, 0.01, 0.6, ps_max=4.0)
    names = [n for n, _ in params.named_parameters()]
    inputs = [q.detach().clone().requires_grad_(True) for q in params.parameters()]

    def at(*raws):
        for n, x in zip(names, raws):
            params._parameters[n] = x  # the objective reads the raw tensors through params.values()
        return obj(params)

    assert torch.autograd.gradcheck(at, inputs, eps=1e-6, atol=1e-6)


def test_per_texel_shares_sum_to_the_objective():
    obs, terms, (pd, ps, sigma) = noisy_scene(T=40, seed=5)
    mask = torch.arange(40) % 3 == 0
    obj = Objective(
        lambda a, b, c: predict(terms, a, b, c), obs.intensity, obs.valid, priors=[Prior(mask, ps * 1.3, sigma, 0.5)]
    )
    params = TexelParams(pd * 0.9, ps, sigma * 1.1, 0.01, 0.6)
    with torch.no_grad():
        torch.testing.assert_close(obj.per_texel(params).sum(), obj(params), rtol=1e-10, atol=0)


@pytest.mark.parametrize("guarded", [True, False])
def test_no_texel_ends_a_refinement_worse_than_it_started(guarded):
    """An optimiser that overshoots (Adam at a far too large rate) leaves some texels worse than their start; the
    guard gives them their start back. The control: a smoothness term too small to matter turns the guard off."""
    obs, terms, (pd, ps, sigma) = noisy_scene(T=60, seed=6)
    pairs = None if guarded else neighbour_pairs(TexelGrid(np.arange(60), (6, 10)))
    obj = Objective(
        lambda a, b, c: predict(terms, a, b, c),
        obs.intensity,
        obs.valid,
        smoothness=0.0 if guarded else 1e-12,
        neighbours=pairs,
    )
    params = TexelParams(pd * 1.05, ps * 0.95, sigma * 1.05, 0.01, 0.6)
    with torch.no_grad():
        before = obj.per_texel(params)
    refine(params, obj, "adam", 15, learning_rate=2.0)
    with torch.no_grad():
        worse = obj.per_texel(params) > before * (1 + 1e-9)
    assert (not bool(worse.any())) if guarded else int(worse.sum()) > 5


def test_the_smoothing_pairs_cross_the_seams_of_an_atlas():
    """On a cube's atlas every texel at a chart's border is paired with the texel across the cube's edge (half a
    texel on each side: sqrt(0.5) mm apart), and no pair joins charts that only sit side by side in the atlas."""
    from conftest import atlas_cube

    s = atlas_cube(side=8).surface
    pairs = neighbour_pairs(s.neighbours).numpy()
    chart, p = s.extras["chart"], s.positions.numpy()
    seam = chart[pairs[:, 0]] != chart[pairs[:, 1]]
    assert seam.sum() == 12 * 8  # 12 cube edges of 8 texels
    d = np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1)
    assert np.allclose(d[seam], np.sqrt(0.5)) and np.allclose(d[~seam], 1.0)
