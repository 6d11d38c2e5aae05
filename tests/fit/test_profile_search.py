"""The sigma search by variable projection (torchrefl.fit.profile_search): the grid finds each texel's basin, the
golden-section steps narrow sigma between the grid values, and the result is never worse than the grid's."""

import pytest
import torch
from conftest import dome_scene, point_light_observations

from torchrefl.fit.profile_search import profile_search, profiled_fit, sigma_grid
from torchrefl.transport.local import local_terms, predict

T = 120


def scene(noise: float = 0.0):
    nrm, pos, lights, cam = dome_scene(T=T, seed=4)
    obs = point_light_observations(nrm, pos, lights[::2], cam, intensity=2.0e4)
    terms = local_terms("torrance_sparrow", torch.as_tensor(nrm), obs)
    g = torch.Generator().manual_seed(5)
    truth = (
        0.2 + 0.5 * torch.rand(T, 3, generator=g, dtype=torch.float64),
        0.1 + 0.4 * torch.rand(T, 1, generator=g, dtype=torch.float64).expand(T, 3),
        0.06 + 0.3 * torch.rand(T, generator=g, dtype=torch.float64),
    )
    intensity = predict(terms, *truth)
    intensity = intensity + noise * torch.randn(intensity.shape, generator=g, dtype=torch.float64)
    return terms, intensity, obs.valid, truth


def relative(a, b):
    return ((a - b).abs() / b).median()


def test_narrowed_search_lands_on_the_truth_between_grid_values():
    terms, intensity, mask, (pd, ps, sigma) = scene()
    grid = sigma_grid(0.01, 0.6, 32)  # values 14 % apart
    pd_g, ps_g, sg_g, _ = profile_search(terms, intensity, mask, grid, golden_steps=0)
    pd_n, ps_n, sg_n, _ = profile_search(terms, intensity, mask, grid)
    assert relative(sg_g, sigma) > 0.02  # the grid alone is a grid step off
    assert relative(sg_n, sigma) < 0.003
    assert relative(ps_n, ps) < 0.005
    assert relative(pd_n, pd) < 0.001


@pytest.mark.parametrize("ps_channels", [1, 3])
def test_narrowing_never_raises_the_error_over_the_grid(ps_channels):
    terms, intensity, mask, _ = scene(noise=0.01)
    grid = sigma_grid(0.01, 0.6, 16)
    *_, err_g = profile_search(terms, intensity, mask, grid, ps_channels, golden_steps=0)
    *_, err_n = profile_search(terms, intensity, mask, grid, ps_channels)
    assert (err_n <= err_g + 1e-12).all()
    assert (err_n < err_g * (1 - 1e-4)).float().mean() > 0.5


def test_shared_lobe_is_narrowed_too():
    terms, intensity, mask, (pd, _, _) = scene()
    intensity = predict(terms, pd, torch.full((T, 3), 0.3, dtype=torch.float64), torch.full((T,), 0.137).double())
    grid = sigma_grid(0.01, 0.6, 32)
    _, ps_s, sg_s, _ = profile_search(terms, intensity, mask, grid, shared=True)
    assert torch.allclose(sg_s, sg_s[:1].expand(T)) and torch.allclose(ps_s, ps_s[:1].expand_as(ps_s))
    assert abs(float(sg_s[0]) / 0.137 - 1) < 0.003
    assert (ps_s / 0.3 - 1).abs().max() < 0.005


def test_a_texel_whose_truth_is_at_the_grid_bound_stays_in_bounds():
    terms, intensity, mask, (pd, ps, _) = scene()
    at_bound = torch.full((T,), 0.6, dtype=torch.float64)
    intensity = predict(terms, pd, ps, at_bound)
    _, _, sg, err = profile_search(terms, intensity, mask, sigma_grid(0.01, 0.6, 32))
    assert (sg <= 0.6 + 1e-12).all() and (sg >= 0.01 - 1e-12).all()
    assert relative(sg, at_bound) < 1e-3
    assert torch.isfinite(err).all()


@pytest.mark.parametrize("ps_channels", [1, 3])
def test_the_error_is_that_of_the_parameters_returned_also_where_pd_is_held_at_zero(ps_channels):
    """Black channels (Pd = 0) plus noise make the least-squares Pd negative at some sigma; the search must then
    hold Pd at 0 and report the error of what it returns, not of the negative Pd (which once won the search)."""
    terms, intensity, mask, (pd, ps, sigma) = scene()
    pd = pd.clone()
    pd[::2, 2] = 0.0  # every other texel black in blue
    g = torch.Generator().manual_seed(6)
    intensity = predict(terms, pd, ps, sigma) + 0.01 * torch.randn(intensity.shape, generator=g, dtype=torch.float64)
    profile = profiled_fit(terms, intensity, mask, ps_channels)
    held = 0
    for s in sigma_grid(0.01, 0.6, 12):
        pd_s, ps_s, err = profile(s)
        assert (pd_s >= 0).all()
        held += int((pd_s == 0).sum())
        own = (predict(terms, pd_s, ps_s.expand(T, 3), s.expand(T)) - intensity) * mask[..., None]
        assert torch.allclose(err, own.square().sum((0, 2)), rtol=1e-9, atol=1e-12)
    assert held > 0  # the case was exercised
    pd_b, ps_b, sg_b, err_b = profile_search(terms, intensity, mask, sigma_grid(0.01, 0.6, 32), ps_channels)
    own = ((predict(terms, pd_b, ps_b.expand(T, 3), sg_b) - intensity) * mask[..., None]).square().sum((0, 2))
    assert torch.allclose(err_b, own, rtol=1e-9, atol=1e-12)


def test_with_one_ps_per_channel_the_fit_is_the_bounded_least_squares_one():
    """Against scipy's bounded least squares (Pd >= 0, 0 <= Ps <= ps_max) per texel and channel, at one sigma."""
    from scipy.optimize import lsq_linear

    from torchrefl.core.brdf import specular_lobe

    terms, intensity, mask, (pd, ps, sigma) = scene()
    pd = pd.clone()
    pd[::2, 2] = 0.0
    g = torch.Generator().manual_seed(6)
    intensity = predict(terms, pd, ps, sigma) + 0.01 * torch.randn(intensity.shape, generator=g, dtype=torch.float64)
    s = torch.tensor(0.3, dtype=torch.float64)
    pd_s, ps_s, err = profiled_fit(terms, intensity, mask, 3, ps_max=0.6)(s)
    E = specular_lobe(terms.brdf, terms.theta_h, s)[..., None] * terms.specular
    held = 0
    for t in range(0, T, 3):
        best = 0.0
        for c in range(3):
            m = mask[:, t]
            A = torch.stack([terms.diffuse[m, t, c], E[m, t, c]], 1).numpy()
            ref = lsq_linear(A, intensity[m, t, c].numpy(), bounds=([0.0, 0.0], [float("inf"), 0.6]), tol=1e-12)
            best += 2 * ref.cost
            held += int(ref.x[0] <= 1e-12)
        assert abs(float(err[t]) - best) <= 1e-9 * max(best, 1e-12) + 1e-14
    assert held > 0
