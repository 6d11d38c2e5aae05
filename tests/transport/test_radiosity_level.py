"""Radiosity level: prediction reduces to local without form factors, inverse radiosity is exact
on exact data, gradients flow into Pd."""

import math

import torch

from conftest import dome_scene, point_light_observations
from torchrefl.transport.local import local_terms, predict
from torchrefl.transport.radiosity_level import PatchMap, indirect_irradiance, inverse_radiosity, predict_radiosity


def scene(T=24, seed=0):
    nrm, pos, lights, cam = dome_scene(T=T, seed=seed)
    obs = point_light_observations(nrm, pos, lights[::9], cam)
    terms = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs)
    g = torch.Generator().manual_seed(seed)
    areas = 0.5 + torch.rand(T, generator=g, dtype=torch.float64)
    G = torch.rand(T, T, generator=g, dtype=torch.float64)
    G = G + G.t()
    G.fill_diagonal_(0)
    F = G / areas[:, None]
    F = F / F.sum(1).max() * 0.6                      # reciprocal, open
    patches = PatchMap(torch.arange(T), areas, T)
    pd = 0.2 + 0.6 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    return obs, terms, patches, F, pd


def test_without_form_factors_it_is_the_local_prediction():
    obs, terms, patches, F, pd = scene()
    ps = torch.full_like(pd, 0.2)
    sigma = torch.full((pd.shape[0],), 0.1, dtype=torch.float64)
    a = predict_radiosity(terms, obs.kappa, pd, ps, sigma, patches, torch.zeros_like(F))
    torch.testing.assert_close(a, predict(terms, pd, ps, sigma))


def test_interreflection_adds_light_and_matches_the_series():
    """H equals the Neumann series F (rho E) + F rho F (rho E) + ... summed by hand."""
    obs, terms, patches, F, pd = scene()
    H = indirect_irradiance(terms, obs.kappa, pd, patches, F)
    E = terms.diffuse * (math.pi / obs.kappa)
    B = pd[None] * E
    total = torch.zeros_like(E)
    for _ in range(200):
        bounce = torch.einsum("uv,pvc->puc", F, B)
        total = total + bounce
        B = pd[None] * bounce
    torch.testing.assert_close(H, total, rtol=1e-9, atol=1e-12)
    assert (H >= 0).all() and H.sum() > 0


def test_inverse_radiosity_is_exact_on_exact_data():
    obs, terms, patches, F, pd = scene()
    zeros = torch.zeros_like(pd)
    sigma = torch.full((pd.shape[0],), 0.1, dtype=torch.float64)
    obs.intensity = predict_radiosity(terms, obs.kappa, pd, zeros, sigma, patches, F)
    rho, det = inverse_radiosity(terms, obs.kappa, obs.intensity, torch.ones_like(obs.valid), patches, F)
    assert det.all()
    torch.testing.assert_close(rho, pd, rtol=1e-9, atol=1e-12)
    # the local closed form is biased upwards by the interreflection
    local = (obs.intensity / terms.diffuse.clamp_min(1e-30))[0]
    assert (local[terms.diffuse[0, :, 0] > 0] > pd[terms.diffuse[0, :, 0] > 0] + 1e-6).all()


def test_gradcheck_through_the_solve():
    obs, terms, patches, F, pd = scene(T=6)
    ps = torch.full((6, 3), 0.2, dtype=torch.float64)
    sigma = torch.full((6,), 0.1, dtype=torch.float64)
    f = lambda p: predict_radiosity(terms, obs.kappa, p, ps, sigma, patches, F)
    assert torch.autograd.gradcheck(f, (pd.clone().requires_grad_(),))


def test_patch_means_are_area_weighted():
    areas = torch.tensor([1.0, 3.0, 2.0], dtype=torch.float64)
    pm = PatchMap(torch.tensor([0, 0, 1]), areas, 2)
    x = torch.tensor([[1.0], [5.0], [7.0]], dtype=torch.float64)
    torch.testing.assert_close(pm.mean(x), torch.tensor([[4.0], [7.0]], dtype=torch.float64))
    torch.testing.assert_close(pm.scatter(pm.mean(x)), torch.tensor([[4.0], [4.0], [7.0]], dtype=torch.float64))
