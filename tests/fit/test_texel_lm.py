"""Levenberg-Marquardt per texel: recovers known parameters, never raises a texel's cost, reaches a lower
objective than LBFGS, holds what it does not train, follows the priors, and its normal equations carry the
objective's exact gradient (float64)."""

import numpy as np
import pytest
import torch
from conftest import noisy_glossy_scene as glossy_scene

from torchrefl.config import Config
from torchrefl.core.observation_classes import T_SPEC, classify
from torchrefl.core.params import TexelParams
from torchrefl.core.texel_grid import TexelGrid
from torchrefl.errors import FitError
from torchrefl.fit.closed_form import closed_form
from torchrefl.fit.pipeline import refinement_optimizer
from torchrefl.fit.refine import Objective, Prior, neighbour_pairs, refine, robust_loss
from torchrefl.fit.texel_lm import _normal_equations, _TexelProblem, irls_weight, levenberg_marquardt
from torchrefl.transport.local import predict


def start(obs, terms):
    cls = classify(terms.theta_h, obs.valid)
    cf = closed_form(terms, obs.intensity, cls, obs.valid, 3, 0.01, 0.6)
    ps0 = torch.where(cf.spec_determined[:, None], cf.ps, torch.full_like(cf.ps, 0.2))
    sg0 = torch.where(cf.spec_determined, cf.sigma, torch.full_like(cf.sigma, 0.15))
    return TexelParams(cf.pd, ps0, sg0, 0.01, 0.6, ps_max=4.0)


def objective(obs, terms, priors=(), loss="huber"):
    model = lambda a, b, c: predict(terms, a, b, c)
    return Objective(model, obs.intensity, obs.valid, loss=loss, loss_scale_8bit=2.0, priors=list(priors))


def local_model(terms):
    return lambda pd: lambda a, b, c: predict(terms, a, b, c)


def test_recovers_the_truth_and_beats_lbfgs():
    obs, terms, (pd, ps, sigma) = glossy_scene()
    obj = objective(obs, terms)
    params = start(obs, terms)
    before = obj.per_texel(params).detach()
    hist = levenberg_marquardt(params, obj, local_model(terms), 60)
    epd, eps, esg = (x.detach() for x in params.values())
    assert torch.sqrt(((epd - pd) ** 2).mean()) < 0.01
    assert ((esg - sigma).abs() / sigma).median() < 0.05
    assert ((eps.mean(-1) - ps.mean(-1)).abs() / ps.mean(-1)).median() < 0.05
    # every texel's own cost fell or stayed (its steps are kept only where they lower it)
    assert bool((obj.per_texel(params).detach() <= before * (1 + 1e-12)).all())
    assert all(b <= a * (1 + 1e-12) for a, b in zip(hist, hist[1:]))
    lbfgs = start(obs, terms)
    refine(lbfgs, obj, "lbfgs", 80)
    assert float(obj(params)) < float(obj(lbfgs))


def test_noise_free_images_are_fitted_exactly():
    obs, terms, (pd, ps, sigma) = glossy_scene(T=120, seed=3, noise=0.0)
    params = start(obs, terms)
    with torch.no_grad():
        params.assign(pd * 1.2, ps * 0.7, sigma * 1.3)
    obj = objective(obs, terms, loss="l2")
    levenberg_marquardt(params, obj, local_model(terms), 60)
    # texels with two highlights: their Ps and sigma are determined
    seen = (classify(terms.theta_h, obs.valid) == T_SPEC).sum(0) >= 2
    assert int(seen.sum()) > 50
    torch.testing.assert_close(params.pd().detach()[seen], pd[seen], rtol=1e-4, atol=1e-5)
    rel = (params.sigma().detach()[seen] / sigma[seen] - 1).abs()
    assert float((rel < 1e-3).double().mean()) > 0.97, rel.max()  # a texel whose highlights are faint tails may lag


def test_trains_only_the_named_tensors():
    obs, terms, _ = glossy_scene(T=80, seed=1)
    params = start(obs, terms)
    ps0, sg0, pd0 = params.raw_ps.detach().clone(), params.raw_sigma.detach().clone(), params.raw_pd.detach().clone()
    levenberg_marquardt(params, objective(obs, terms), local_model(terms), 10, train=[params.raw_pd])
    assert torch.equal(params.raw_ps.detach(), ps0) and torch.equal(params.raw_sigma.detach(), sg0)
    assert not torch.equal(params.raw_pd.detach(), pd0)


def test_a_texel_without_observations_goes_to_its_prior():
    obs, terms, _ = glossy_scene(T=60, seed=2)
    obs.valid[:, 0] = False
    params = start(obs, terms)
    T = params.num_texels
    prior = Prior(torch.arange(T) == 0, torch.full((T, 3), 0.3, dtype=torch.float64), torch.full((T,), 0.2), 0.1)
    pd0 = params.pd().detach()[0].clone()
    levenberg_marquardt(params, objective(obs, terms, [prior]), local_model(terms), 40)
    torch.testing.assert_close(params.ps().detach()[0], torch.full((3,), 0.3, dtype=torch.float64), rtol=1e-3, atol=0)
    assert abs(float(params.sigma().detach()[0]) - 0.2) < 2e-4
    torch.testing.assert_close(params.pd().detach()[0], pd0)  # no observation, no pull: Pd stays


@pytest.mark.parametrize("loss", ["l2", "huber", "cauchy"])
def test_normal_equations_carry_the_exact_gradient_float64(loss):
    """J^T W r of the normal equations is the gradient of the per-texel cost (robust loss + prior) by autograd:
    the forward-mode Jacobian and the reweighting are right."""
    obs, terms, _ = glossy_scene(T=40, seed=5, noise=4.0)
    params = start(obs, terms)
    T = params.num_texels
    prior = Prior(torch.arange(T) % 2 == 0, torch.full((T, 3), 0.3, dtype=torch.float64), torch.full((T,), 0.2), 0.5)
    obj = objective(obs, terms, [prior], loss=loss)
    problem = _TexelProblem(params, obj, lambda a, b, c: predict(terms, a, b, c))
    x = [q.detach().clone().requires_grad_(True) for q in (params.raw_pd, params.raw_ps, params.raw_sigma)]
    r, pulls = problem.residuals(*x)
    cost = problem.cost(r, pulls).sum()
    grads = torch.autograd.grad(cost, x)
    columns = [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2), (2, 0)]
    _, g, r0, pulls0 = _normal_equations(problem, [q.detach() for q in x], columns)
    torch.testing.assert_close(r0, r.detach())
    torch.testing.assert_close(pulls0, pulls.detach())
    expected = torch.cat([grads[0], grads[1], grads[2][:, None]], 1)
    torch.testing.assert_close(g, expected, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("kind", ["l2", "huber", "cauchy"])
def test_irls_weight_is_the_robust_losses_derivative_over_r(kind):
    r = torch.linspace(-9, 9, 37, dtype=torch.float64).requires_grad_(True)
    (d,) = torch.autograd.grad(robust_loss(r, kind, 2.0).sum(), r)
    torch.testing.assert_close(irls_weight(r.detach(), kind, 2.0) * r.detach(), d)


def test_coupled_objectives_are_refused_and_the_pipeline_uses_lbfgs():
    obs, terms, _ = glossy_scene(T=30, seed=6)
    shared = TexelParams(
        torch.full((30, 3), 0.5, dtype=torch.float64),
        torch.full((30, 3), 0.2, dtype=torch.float64),
        torch.full((30,), 0.1, dtype=torch.float64),
        0.01,
        0.6,
        shared_specular=True,
    )
    obj = objective(obs, terms)
    with pytest.raises(FitError, match="couples texels"):
        levenberg_marquardt(shared, obj, local_model(terms), 5)
    smooth = Objective(
        obj.predict,
        obs.intensity,
        obs.valid,
        smoothness=1.0,
        neighbours=neighbour_pairs(TexelGrid(np.arange(30), (5, 6))),
    )
    with pytest.raises(FitError, match="couples texels"):
        levenberg_marquardt(start(obs, terms), smooth, local_model(terms), 5)
    cfg = Config()
    assert cfg.fit.optimizer == "lm"
    assert refinement_optimizer(cfg, shared) == "lbfgs"
    assert refinement_optimizer(cfg, start(obs, terms)) == "lm"
    cfg.fit.smoothness = 1.0
    assert refinement_optimizer(cfg, start(obs, terms)) == "lbfgs"
    cfg.fit.optimizer = "adam"
    assert refinement_optimizer(cfg, shared) == "adam"


def test_a_texel_nothing_constrains_stays_where_it_is():
    """No observation and no prior: a zero normal matrix, no step, no error; the other texels still fit."""
    obs, terms, (pd, _, _) = glossy_scene(T=40, seed=7)
    obs.valid[:, 3] = False
    params = start(obs, terms)
    before = [q.detach().clone() for q in (params.raw_pd, params.raw_ps, params.raw_sigma)]
    levenberg_marquardt(params, objective(obs, terms), local_model(terms), 20)
    after = (params.raw_pd, params.raw_ps, params.raw_sigma)
    assert all(torch.equal(a.detach()[3], b[3]) for a, b in zip(after, before))
    assert all(torch.isfinite(q).all() for q in after)
    assert not torch.equal(params.raw_pd.detach()[0], before[0][0])


def test_converged_texels_stop_being_evaluated_and_skipped_ones_are_left_alone():
    """Noise-free images: the texels started at the truth leave the evaluated set after the first iteration, those
    in skip are never evaluated and keep their values bit for bit, the rest still reach the truth."""
    obs, terms, (pd, ps, sigma) = glossy_scene(T=60, seed=3, noise=0.0)
    params = start(obs, terms)
    T = len(pd)
    skip = torch.arange(T) % 20 == 1  # three: their cost counts in the objective whose progress stops the loop
    at_truth = (torch.arange(T) % 3 == 0) & ~skip
    with torch.no_grad():
        params.assign(
            torch.where(at_truth[:, None], pd, pd * 1.2),
            torch.where(at_truth[:, None], ps, ps * 0.7),
            torch.where(at_truth, sigma, sigma * 1.3),
        )
    raw = [q.detach().clone() for q in (params.raw_pd, params.raw_ps, params.raw_sigma)]
    seen: list[torch.Tensor] = []

    def texels_model(pd_at, index):
        seen.append(index.clone())
        return lambda a, b, c: predict(terms.texels(index), a, b, c)

    levenberg_marquardt(
        params, objective(obs, terms, loss="l2"), local_model(terms), 60, skip=skip, texels_model=texels_model
    )
    assert len(seen) > 3
    assert not bool(skip[torch.cat(seen)].any())
    assert not bool(at_truth[torch.cat(seen[1:])].any())
    assert int((~skip & ~at_truth)[seen[1]].sum()) > 0
    for q, r in zip((params.raw_pd, params.raw_ps, params.raw_sigma), raw):
        assert torch.equal(q.detach()[skip], r[skip])
    spec = (classify(terms.theta_h, obs.valid) == T_SPEC).sum(0) >= 2
    moved = ~skip & ~at_truth & spec
    torch.testing.assert_close(params.pd().detach()[moved], pd[moved], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(params.pd().detach()[at_truth], pd[at_truth], rtol=1e-6, atol=1e-7)
