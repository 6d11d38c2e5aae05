"""Minnaert's exponent from the diffuse-only observations (torchrefl.fit.diffuse_shape)."""

import math

import pytest
import torch
from conftest import dome_scene, point_light_observations

from torchrefl.core.observation_classes import T_DIFF, classify
from torchrefl.errors import FitError
from torchrefl.fit.diffuse_shape import fit_minnaert_exponent
from torchrefl.transport.local import local_terms, render_reference


def capture(k_true, noise_dn=0.0, T=400, seed=0):
    """Observations of the dome scene rendered with a Minnaert diffuse part of exponent k_true, a specular
    lobe, sensor noise and 8-bit quantisation; returns Lambertian terms, intensities and the T_diff mask."""
    nrm, pos, lights, cam = dome_scene(T=T, seed=seed)
    obs = point_light_observations(nrm, pos, lights, cam, intensity=6.0e4)
    g = torch.Generator().manual_seed(seed)
    pd = 0.2 + 0.6 * torch.rand(T, 3, generator=g, dtype=torch.float64)
    ps = torch.full((T, 3), 0.3, dtype=torch.float64)
    sigma = torch.full((T,), 0.1, dtype=torch.float64)
    n = torch.as_tensor(nrm)
    i = render_reference("torrance_sparrow", n, obs, pd, ps, sigma, k_true)
    i = i + noise_dn / 255.0 * torch.randn(i.shape, generator=g, dtype=torch.float64)
    i = torch.round(i.clamp(0, 1) * 255.0) / 255.0
    terms = local_terms("torrance_sparrow", n, obs)
    ok = obs.valid & (i.max(-1).values < 0.99) & (terms.cos_l > 0.02) & (terms.cos_v > 0.05)
    diffuse_only = classify(terms.theta_h, ok, 45.0, 15.0) == T_DIFF
    return terms, i, diffuse_only


@pytest.mark.parametrize("k_true", [0.8, 1.0, 1.1, 1.4])
def test_recovers_the_exponent_of_the_rendering(k_true):
    terms, i, mask = capture(k_true, noise_dn=0.3)
    assert mask.sum() > 2000
    shape = fit_minnaert_exponent(terms, i, mask)
    assert abs(shape.k - k_true) < 0.01
    assert shape.observations == int(mask.sum())
    assert shape.mse_8bit <= shape.mse_lambert_8bit + 1e-12
    # the residual left at the fitted k is the sensor's: noise (0.3 DN) and 8-bit quantisation (1/12 DN^2)
    assert shape.mse_8bit < 0.3**2 + 1.0 / 12 + 0.05
    if abs(k_true - 1.0) > 0.05:
        assert shape.mse_lambert_8bit > 2 * shape.mse_8bit


def test_exponent_at_the_search_bounds():
    terms, i, mask = capture(2.0)
    assert fit_minnaert_exponent(terms, i, mask).k == pytest.approx(2.0, abs=0.01)
    assert fit_minnaert_exponent(terms, i, mask, low=0.5, high=1.5).k == pytest.approx(1.5, abs=1e-3)


def test_no_diffuse_observation_is_a_clear_error():
    terms, i, mask = capture(1.0)
    with pytest.raises(FitError, match="reflectance.minnaert_k"):
        fit_minnaert_exponent(terms, i, torch.zeros_like(mask))


def test_needs_lambertian_terms():
    terms, i, mask = capture(1.0)
    nrm, pos, lights, cam = dome_scene(T=400)
    obs = point_light_observations(nrm, pos, lights, cam)
    with pytest.raises(ValueError, match="Lambertian"):
        fit_minnaert_exponent(local_terms("torrance_sparrow", torch.as_tensor(nrm), obs, diffuse_exponent=1.2), i, mask)
    assert math.isfinite(fit_minnaert_exponent(terms, i, mask).k)
