"""No NaN or inf in outputs or gradients across a grid of extremes; float32 agrees with float64."""

import itertools

import pytest
import torch
from conftest import dome_scene, point_light_observations

from torchrefl.core.observation_classes import classify
from torchrefl.core.params import TexelParams
from torchrefl.fit.closed_form import closed_form
from torchrefl.fit.profile_search import profile_search, sigma_grid
from torchrefl.fit.refine import Objective, Prior, refine
from torchrefl.fit.texel_lm import levenberg_marquardt
from torchrefl.transport.local import local_terms, predict

MODELS = ["torrance_sparrow", "ward", "ward_normalised"]


def extreme_scene(dtype):
    nrm, pos, lights, cam = dome_scene(T=64, seed=9)
    pos_t = torch.as_tensor(pos)
    n_t = torch.as_tensor(nrm)
    near = (pos_t[:1] + 1.0 * n_t[:1]).numpy()  # a light 1 mm from texel 0
    grazing = (
        pos_t[1:2] + torch.tensor([[1000.0, 0.0, 0.0]], dtype=pos_t.dtype)
    ).numpy()  # almost in the tangent plane
    L = torch.cat([torch.as_tensor(lights[::8]), torch.as_tensor(near), torch.as_tensor(grazing)]).numpy()
    obs = point_light_observations(nrm, pos, L, cam, dtype=dtype)
    P, T = obs.valid.shape
    g = torch.Generator().manual_seed(0)
    obs.intensity = torch.rand(P, T, 3, generator=g, dtype=dtype) * 0.5
    obs.intensity[:, :8] = 0.0  # black texels
    obs.intensity[:, 8:16] = 1.0  # saturated texels
    obs.saturated[:, 8:16] = True
    obs.valid[:, 8:16] = False
    return obs, n_t.to(dtype)


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_objective_and_gradients_finite_at_extremes(model, dtype):
    obs, n = extreme_scene(dtype)
    terms = local_terms(model, n, obs)
    T = n.shape[0]
    for pd_v, sg_v in itertools.product((0.0, 1.0), (0.01, 0.6)):
        params = TexelParams(
            torch.full((T, 3), pd_v, dtype=dtype),
            torch.full((T, 3), 0.5, dtype=dtype),
            torch.full((T,), sg_v, dtype=dtype),
            0.01,
            0.6,
            init_floor=1e-6,
            ps_max=4.0,
        )
        obj = Objective(
            lambda a, b, c: predict(terms, a, b, c),
            obs.intensity,
            obs.valid,
            priors=[
                Prior(
                    torch.ones(T, dtype=torch.bool),
                    torch.full((T, 3), 0.1, dtype=dtype),
                    torch.full((T,), 0.1, dtype=dtype),
                    0.1,
                )
            ],
            smoothness=0.0,
        )
        loss = obj(params)
        assert torch.isfinite(loss)
        loss.backward()
        for p in params.parameters():
            assert torch.isfinite(p.grad).all()


def refine_with(optimizer, params, obj, iterations):
    """refine, or the per-texel Levenberg-Marquardt on the same (local, texel-by-texel) model."""
    if optimizer == "lm":
        return levenberg_marquardt(params, obj, lambda pd: obj.predict, iterations)
    return refine(params, obj, optimizer, iterations)


@pytest.mark.parametrize("optimizer", ["lbfgs", "lm"])
@pytest.mark.parametrize("model", MODELS)
def test_whole_local_fit_is_finite_at_extremes(model, optimizer):
    obs, n = extreme_scene(torch.float32)
    terms = local_terms(model, n, obs)
    cls = classify(terms.theta_h, obs.valid)
    cf = closed_form(terms, obs.intensity, cls, obs.valid, 3, 0.01, 0.6)
    for x in (cf.pd, cf.ps, cf.sigma):
        assert torch.isfinite(x).all()
    pd, ps, sg, err = profile_search(terms, obs.intensity, obs.valid, sigma_grid(0.01, 0.6, 8), ps_max=4.0)
    for x in (pd, ps, sg, err):
        assert torch.isfinite(x).all()
    params = TexelParams(pd, ps, sg, 0.01, 0.6, ps_max=4.0)
    obj = Objective(lambda a, b, c: predict(terms, a, b, c), obs.intensity, obs.valid)
    hist = refine_with(optimizer, params, obj, 10)
    assert all(map(lambda v: v == v, hist))
    for x in params.values():
        assert torch.isfinite(x).all()


@pytest.mark.parametrize("optimizer", ["lbfgs", "lm"])
def test_float32_fit_agrees_with_float64(optimizer):
    out = {}
    for dtype in (torch.float32, torch.float64):
        nrm, pos, lights, cam = dome_scene(T=200, seed=2)
        obs = point_light_observations(nrm, pos, lights[::2], cam, intensity=2.0e4, dtype=dtype)
        n = torch.as_tensor(nrm).to(dtype)
        terms = local_terms("torrance_sparrow", n, obs)
        g = torch.Generator().manual_seed(1)
        truth = (
            0.2 + 0.5 * torch.rand(200, 3, generator=g, dtype=torch.float64).to(dtype),
            0.1 + 0.3 * torch.rand(200, 3, generator=g, dtype=torch.float64).to(dtype),
            0.08 + 0.15 * torch.rand(200, generator=g, dtype=torch.float64).to(dtype),
        )
        obs.intensity = predict(terms, *truth)
        pd, ps, sg, _ = profile_search(terms, obs.intensity, obs.valid, sigma_grid(0.01, 0.6, 32))
        params = TexelParams(pd, ps, sg, 0.01, 0.6)
        obj = Objective(lambda a, b, c: predict(terms, a, b, c), obs.intensity, obs.valid)
        refine_with(optimizer, params, obj, 40)
        out[dtype] = [x.detach().double() for x in params.values()]
    for a, b in zip(out[torch.float32], out[torch.float64]):
        assert (a - b).abs().median() < 1e-3
