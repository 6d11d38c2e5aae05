"""The specular lobe averaged over a footprint's spread of half-angle offsets (torchrefl.core.lobe_spread)."""

from __future__ import annotations

import pytest
import torch

from torchrefl.core.brdf import specular_lobe, specular_lobe_dsigma


@pytest.mark.parametrize("model", ["torrance_sparrow", "ward"])
def test_zero_spread_is_the_lobe_at_the_centre(model):
    theta = torch.linspace(0.0, 0.6, 25, dtype=torch.float64)
    sigma = torch.full((25,), 0.15, dtype=torch.float64)
    D, dD = specular_lobe_dsigma(model, theta, sigma, torch.zeros(25, 2, dtype=torch.float64))
    D0, dD0 = specular_lobe_dsigma(model, theta, sigma)
    assert torch.allclose(D, D0, rtol=1e-12, atol=0) and torch.allclose(dD, dD0, rtol=1e-10, atol=1e-12)


def test_a_shift_moves_the_offset_the_lobe_is_evaluated_at():
    theta, sigma = torch.tensor([0.05, 0.2], dtype=torch.float64), torch.tensor(0.12, dtype=torch.float64)
    spread = torch.tensor([[1e-3, 5e-4, 0.03], [1e-3, 5e-4, -0.04]], dtype=torch.float64)
    moved = torch.tensor([[1e-3, 5e-4, 0.0], [1e-3, 5e-4, 0.0]], dtype=torch.float64)
    got = specular_lobe("torrance_sparrow", theta, sigma, spread)
    assert torch.allclose(got, specular_lobe("torrance_sparrow", theta + spread[:, 2], sigma, moved), rtol=1e-14)


def test_the_spread_lobe_is_the_mean_of_the_lobe_over_gaussian_offsets():
    # offsets d - e, e ~ N(0, diag(along, across)) with d along the first axis: the Torrance-Sparrow lobe's mean
    gen = torch.Generator().manual_seed(0)
    sigma, along, across = 0.1, 3e-3, 8e-4
    for theta in (0.0, 0.08, 0.2):
        e = torch.randn(400_000, 2, generator=gen, dtype=torch.float64) * torch.tensor([along, across]).sqrt()
        d = torch.tensor([theta, 0.0], dtype=torch.float64) - e
        mean = torch.exp(-(d * d).sum(1) / (2 * sigma**2)).mean()
        spread = torch.tensor([along, across], dtype=torch.float64)
        got = specular_lobe("torrance_sparrow", torch.tensor(theta, dtype=torch.float64), torch.tensor(sigma), spread)
        assert float(got) == pytest.approx(float(mean), rel=5e-3)


@pytest.mark.parametrize("columns", [2, 3])
@pytest.mark.parametrize("model", ["torrance_sparrow", "ward"])
def test_the_sigma_derivative_passes_gradcheck(model, columns):
    gen = torch.Generator().manual_seed(1)
    theta = torch.rand(12, generator=gen, dtype=torch.float64) * 0.4
    spread = torch.rand(12, 3, generator=gen, dtype=torch.float64) * torch.tensor(
        [4e-3, 4e-3, 0.1]
    ) - 0.05 * torch.tensor([0, 0, 1])
    spread = spread[:, :columns]
    sigma = (torch.rand(12, generator=gen, dtype=torch.float64) * 0.25 + 0.06).requires_grad_()
    assert torch.autograd.gradcheck(lambda s: specular_lobe(model, theta, s, spread), (sigma,))
    D, dD = specular_lobe_dsigma(model, theta, sigma.detach(), spread)
    (auto,) = torch.autograd.grad(specular_lobe(model, theta, sigma, spread).sum(), sigma)
    assert torch.allclose(dD, auto, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("model", ["torrance_sparrow", "ward"])
def test_extremes_are_finite_and_float32_agrees_with_float64(model):
    # sigma at and below its clamp, grazing half-angles, no spread, a spread far wider than the lobe, large shifts
    theta = torch.tensor([0.0, 1e-6, 0.3, 1.2, 1.5707, 1.5707, 0.05, 0.05], dtype=torch.float64)
    sigma = torch.tensor([1e-9, 1e-3, 0.1, 0.5, 0.3, 1e-9, 0.02, 2.0], dtype=torch.float64)
    spread = torch.tensor(
        [
            [0, 0, 0],
            [1e-8, 0, 0],
            [1e-3, 1e-3, 0.5],
            [0.5, 0.5, -2.0],
            [1.0, 1.0, 0],
            [0, 0, 0],
            [2.0, 1e-6, 0],
            [0, 0, 0],
        ],
        dtype=torch.float64,
    )
    D64, dD64 = specular_lobe_dsigma(model, theta, sigma, spread)
    D32, dD32 = specular_lobe_dsigma(model, theta.float(), sigma.float(), spread.float())
    assert torch.isfinite(D64).all() and torch.isfinite(dD64).all()
    assert torch.isfinite(D32).all() and torch.isfinite(dD32).all()
    scale = D64.abs().max()
    assert torch.allclose(D32.double(), D64, rtol=1e-4, atol=1e-6 * float(scale))
    sig = sigma.clone().requires_grad_()
    (grad,) = torch.autograd.grad(specular_lobe(model, theta, sig, spread).sum(), sig)
    assert torch.isfinite(grad).all()
