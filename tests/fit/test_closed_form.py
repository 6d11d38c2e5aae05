"""Closed forms (eq. 3.3, 3.5) recover known parameters from exact model intensities."""

import math

import pytest
import torch
from conftest import dome_scene, point_light_observations

from torchrefl.core.observation_classes import INVALID, T_DIFF, T_NONE, T_SPEC, classify
from torchrefl.fit.closed_form import closed_form
from torchrefl.transport.local import local_terms, predict


def scene(model, T=400, seed=1, sigma_span=0.08):
    nrm, pos, lights, cam = dome_scene(T=T, seed=seed)
    obs = point_light_observations(nrm, pos, lights, cam)
    g = torch.Generator().manual_seed(seed)
    pd = 0.1 + 0.7 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    ps = 0.1 + 0.4 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    sigma = 0.06 + sigma_span * torch.rand(T, generator=g, dtype=torch.float64)
    terms = local_terms(model, torch.as_tensor(nrm), obs)
    obs.intensity = predict(terms, pd, ps, sigma)
    return obs, terms, pd, ps, sigma


def test_classification_thresholds():
    th = torch.tensor([[math.radians(70), math.radians(60), math.radians(30), math.radians(20), math.radians(5)]])
    valid = torch.tensor([[True, True, True, True, False]])
    cls = classify(th, valid, 60.0, 20.0)
    assert cls.tolist() == [[T_DIFF, T_NONE, T_NONE, T_SPEC, INVALID]]


@pytest.mark.parametrize("model", ["torrance_sparrow", "ward", "ward_normalised"])
def test_exact_data_gives_exact_parameters(model):
    obs, terms, pd, ps, sigma = scene(model)
    cls = classify(terms.theta_h, obs.valid)
    cf = closed_form(terms, obs.intensity, cls, obs.valid, 3, 0.01, 0.6)
    assert cf.pd_from_diffuse.float().mean() > 0.7
    m = cf.pd_from_diffuse
    torch.testing.assert_close(cf.pd[m], pd[m], rtol=1e-9, atol=1e-9)
    det = cf.spec_determined
    assert det.float().mean() > 0.5, "the dome scene gives most texels two T_spec observations"
    # texels where Pd came from a pure-diffuse observation and two T_spec ones: exact
    both = det & m
    torch.testing.assert_close(cf.sigma[both], sigma[both], rtol=1e-6, atol=1e-8)
    torch.testing.assert_close(cf.ps[both], ps[both], rtol=1e-6, atol=1e-8)


def test_rough_lobes_bias_pd_upwards_only_slightly():
    """With rough lobes the T_diff observation still carries a little specular light (the seed's
    approximation): Pd is overestimated, never under, by at most the lobe's residual."""
    obs, terms, pd, ps, sigma = scene("torrance_sparrow", sigma_span=0.25)
    cls = classify(terms.theta_h, obs.valid)
    cf = closed_form(terms, obs.intensity, cls, obs.valid, 3, 0.01, 0.6)
    m = cf.pd_from_diffuse
    err = cf.pd[m] - pd[m]
    assert (err > -1e-9).all() and err.max() < 0.1


def test_two_observations_reproduce_eq_3_5_by_hand():
    """With exactly two T_spec observations the weighted line is the seed's pair of equations."""
    obs, terms, pd, ps, sigma = scene("torrance_sparrow", T=50, seed=3)
    cls = classify(terms.theta_h, obs.valid)
    t = int(torch.nonzero((cls == T_SPEC).sum(0) >= 2)[0])
    spec_idx = torch.nonzero(cls[:, t] == T_SPEC)[:, 0]
    order = terms.theta_h[spec_idx, t].argsort()
    keep = spec_idx[order[:2]]
    cls2 = cls.clone()
    drop = spec_idx[order[2:]]
    cls2[drop, t] = T_NONE
    cf = closed_form(terms, obs.intensity, cls2, obs.valid, 3, 0.01, 0.6)
    # eq. 3.4-3.5 by hand, with the seed's Y/C^2 (kappa = pi, so B = Y/C^2 / cos_v)
    i = obs.intensity[:, t].mean(-1)
    Yc = obs.light_intensity[:, 0] * obs.falloff[:, t]
    i_s = i - cf.pd[t].mean() * Yc * terms.cos_l[:, t]
    a1, a2 = (i_s[keep] * terms.cos_v[keep, t] / Yc[keep]).tolist()
    th1, th2 = terms.theta_h[keep, t].tolist()
    sig = math.sqrt((th2**2 - th1**2) / (2 * math.log(a1 / a2)))
    assert abs(float(cf.sigma[t]) - sig) < 1e-9
    assert abs(float(cf.sigma[t]) - float(sigma[t])) < 1e-6


def test_undetermined_when_one_specular_observation():
    obs, terms, pd, ps, sigma = scene("torrance_sparrow", T=30, seed=4)
    cls = classify(terms.theta_h, obs.valid)
    for t in range(30):
        spec = torch.nonzero(cls[:, t] == T_SPEC)[:, 0]
        cls[spec[1:], t] = T_NONE
    cf = closed_form(terms, obs.intensity, cls, obs.valid, 3, 0.01, 0.6)
    assert not cf.spec_determined.any()


def test_no_diffuse_observation_gives_upper_bound():
    obs, terms, pd, ps, sigma = scene("torrance_sparrow", T=30, seed=5)
    cls = classify(terms.theta_h, obs.valid)
    cls[cls == T_DIFF] = T_NONE
    cf = closed_form(terms, obs.intensity, cls, obs.valid, 3, 0.01, 0.6)
    assert not cf.pd_from_diffuse.any()
    assert (cf.pd >= pd - 1e-9).all()
