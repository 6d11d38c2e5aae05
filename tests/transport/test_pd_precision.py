"""Pd's median std from the images' slope in Pd: against the spread of Pd refitted by hand (per texel and channel,
linear least squares) over independent noise draws, and against fit.uncertainty's Pd block with the lobe held at a
known noise."""

import torch
from conftest import noisy_glossy_scene as glossy_scene

from torchrefl.fit.uncertainty import ParameterRanges, fitted_covariance, texel_evidence
from torchrefl.transport.local import predict
from torchrefl.transport.pd_precision import median_pd_std


def test_the_median_std_is_the_spread_of_refitted_pd():
    obs, terms, (pd, ps, sigma) = glossy_scene(T=120, seed=7, noise=0.0)
    model = lambda a, b, c: predict(terms, a, b, c)  # noqa: E731
    mask = obs.valid
    clean = model(pd, ps, sigma)
    g = torch.Generator().manual_seed(8)
    noise = 0.8 / 255
    # the slope by finite difference of the renderer, and Pd refitted per texel and channel by hand
    slope = model(pd + 1e-3, ps, sigma) - model(pd - 1e-3, ps, sigma)
    slope = slope / 2e-3 * mask[..., None]
    draws, stds = [], []
    for _ in range(40):
        images = clean + noise * torch.randn(clean.shape, generator=g, dtype=torch.float64)
        r = (images - clean) * mask[..., None]
        draws.append(pd + (slope * r).sum(0) / slope.square().sum(0))
        stds.append(median_pd_std(model, pd, ps, sigma, images, mask))
    spread = torch.stack(draws).std(0)  # (T, 3) over the draws
    seen = mask.any(0)
    assert abs(float(spread[seen].median()) / (sum(stds) / len(stds)) - 1) < 0.1


def test_agrees_with_the_uncertainty_s_pd_block():
    obs, terms, (pd, ps, sigma) = glossy_scene(T=80, seed=9, noise=0.5)
    model = lambda a, b, c: predict(terms, a, b, c)  # noqa: E731
    held = torch.zeros(80, dtype=torch.bool)  # the lobe held: Pd's block alone (fit.uncertainty.fitted_covariance)
    ranges = ParameterRanges(ps_max=4.0, sigma_min=0.01, sigma_max=0.6)
    noise = float(median_pd_std(model, pd, ps, sigma, obs.intensity, obs.valid))
    ev = texel_evidence(model, pd, ps, sigma, obs.intensity, obs.valid, "huber", 3.0)
    info = ev.per_channel.scaled(torch.full((3,), 0.577, dtype=torch.float64))
    cov = fitted_covariance(info, ranges.prior_var(ps.shape[1]), held)
    pd_std = cov[:, :3, :3].diagonal(dim1=1, dim2=2).sqrt()
    # same noise level (0.5 DN and 8-bit rounding, sqrt(0.25 + 1/12)): the same median std within the MAD's scatter
    assert abs(noise / float(pd_std.median()) - 1) < 0.1


def test_no_fitted_observation_is_no_precision():
    obs, terms, (pd, ps, sigma) = glossy_scene(T=10, seed=1, noise=0.5)
    model = lambda a, b, c: predict(terms, a, b, c)  # noqa: E731
    none = torch.zeros_like(obs.valid)
    assert median_pd_std(model, pd, ps, sigma, obs.intensity, none) == float("inf")
