"""The lobe sampler's closed forms against their definitions: lobe_constants / lobe_over_pdf against
brdf.specular_lobe over half_vector_pdf, lobe_theta with precomputed constants, float32 at the extremes."""

import math

import numpy as np
import pytest
import torch

from torchrefl.core import brdf
from torchrefl.core.lobe_sampling import half_vector_pdf, lobe_constants, lobe_over_pdf, lobe_theta


@pytest.mark.parametrize("lobe,model", [("torrance_sparrow", "torrance_sparrow"), ("ward", "ward")])
@pytest.mark.parametrize("sigma", [brdf.SIGMA_EPS, 0.01, 0.08, 0.5, 1.2])
def test_lobe_over_pdf_is_the_lobe_over_the_half_vector_pdf(lobe, model, sigma):
    # angles where both are well above underflow, so that the plain quotient is accurate
    top = min(math.pi / 2 - 1e-3, 5 * sigma) if lobe == "torrance_sparrow" else math.atan(5 * sigma)
    theta = np.linspace(1e-6, top, 200)
    sig = np.full_like(theta, sigma)
    D = brdf.specular_lobe(model, torch.from_numpy(theta), torch.from_numpy(sig)).numpy()
    p = half_vector_pdf(lobe, np.cos(theta), sig)
    trunc, ratio = lobe_constants(lobe, sig)
    ours = lobe_over_pdf(lobe, theta, np.cos(theta), np.sin(theta), ratio)
    np.testing.assert_allclose(ours, D / p, rtol=1e-6)  # the quotient loses digits to cos near theta = 0


@pytest.mark.parametrize("lobe", ["torrance_sparrow", "ward"])
def test_lobe_theta_with_precomputed_constants_is_the_plain_sampler(lobe):
    rng = np.random.default_rng(0)
    sigma = rng.uniform(brdf.SIGMA_EPS, 1.5, 10_000)
    u = rng.random(10_000)
    trunc, _ = lobe_constants(lobe, sigma)
    np.testing.assert_array_equal(lobe_theta(lobe, sigma, u, trunc), lobe_theta(lobe, sigma, u))


@pytest.mark.parametrize("lobe", ["torrance_sparrow", "ward"])
def test_float32_closed_forms_are_finite_at_the_extremes_and_match_float64(lobe):
    sigma = np.array([brdf.SIGMA_EPS, brdf.SIGMA_EPS, 0.05, 1.5, 1.5, brdf.SIGMA_EPS])
    u = np.array([0.0, 1 - 2**-24, 0.5, 0.0, 1 - 2**-24, 0.999])  # float32's largest value below 1
    trunc, ratio = lobe_constants(lobe, sigma)
    th64 = lobe_theta(lobe, sigma, u, trunc)
    th32 = lobe_theta(lobe, sigma.astype(np.float32), u.astype(np.float32), trunc.astype(np.float32))
    assert th32.dtype == np.float32 and np.isfinite(th32).all() and (th32 >= 0).all() and (th32 <= math.pi / 2).all()
    np.testing.assert_allclose(th32, th64, rtol=1e-4, atol=1e-7)
    r32 = lobe_over_pdf(lobe, th32, np.cos(th32), np.sin(th32), ratio.astype(np.float32))
    r64 = lobe_over_pdf(lobe, th64, np.cos(th64), np.sin(th64), ratio)
    assert r32.dtype == np.float32 and np.isfinite(r32).all()
    np.testing.assert_allclose(r32, r64, rtol=1e-4, atol=1e-12)


def test_unknown_lobe_is_refused():
    with pytest.raises(Exception, match="no lobe sampler"):
        lobe_constants("phong", np.ones(2))
