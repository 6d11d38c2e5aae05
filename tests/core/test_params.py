"""Constraint-preserving parametrisation: exact round trip, bounds, finite gradients at the bounds."""

import torch

from torchrefl.core.params import TexelParams, inverse_softplus_b, softplus_b


def test_round_trip_of_initial_values():
    pd = torch.tensor([[0.0, 1e-4, 0.5], [1.0, 0.02, 2.0]], dtype=torch.float64)
    ps = torch.tensor([[0.3], [1e-5]], dtype=torch.float64)
    sigma = torch.tensor([0.05, 0.3], dtype=torch.float64)
    p = TexelParams(pd, ps, sigma, 0.01, 0.6, init_floor=1e-6)
    a, b, c = p.values()
    torch.testing.assert_close(a, pd.clamp_min(1e-6), atol=2e-6, rtol=1e-6)
    torch.testing.assert_close(b, ps.clamp_min(1e-6), atol=2e-6, rtol=1e-6)
    torch.testing.assert_close(c, sigma, atol=1e-6, rtol=0)


def test_starts_on_a_bound_are_moved_inside_so_they_can_leave_it():
    """A sigma started on its bound would be pinned (the sigmoid is flat there): it starts 1 % inside
    and the gradient with respect to its raw parameter is not negligible."""
    sigma = torch.tensor([0.01, 0.6], dtype=torch.float64)
    p = TexelParams(torch.full((2, 3), 0.5), torch.full((2, 1), 0.3), sigma, 0.01, 0.6)
    c = p.sigma()
    assert (c > 0.01).all() and (c < 0.6).all()
    torch.testing.assert_close(c, torch.tensor([0.01 + 0.0059, 0.6 - 0.0059], dtype=c.dtype), atol=1e-4, rtol=0)
    c.sum().backward()
    assert (p.raw_sigma.grad > 0.005 * 0.59).all()


def test_init_floor_keeps_parameters_movable():
    p = TexelParams(torch.zeros(2, 3), torch.zeros(2, 1), torch.full((2,), 0.1), 0.01, 0.6)
    assert (p.pd() >= 0.01 - 1e-6).all()
    (p.pd().sum() + p.ps().sum()).backward()
    assert (p.raw_pd.grad > 0.1).all() and (p.raw_ps.grad > 0.1).all()


def test_any_raw_value_stays_feasible_with_finite_gradients():
    raw = torch.tensor([-1e4, -50.0, 0.0, 50.0, 1e4], dtype=torch.float64, requires_grad=True)
    y = softplus_b(raw)
    assert (y >= 0).all() and torch.isfinite(y).all()
    y.sum().backward()
    assert torch.isfinite(raw.grad).all()
    p = TexelParams(torch.ones(5, 3), torch.ones(5, 3), torch.full((5,), 0.1), 0.01, 0.6)
    with torch.no_grad():
        p.raw_sigma.copy_(raw.detach().float())
    s = p.sigma()
    assert (s >= 0.01).all() and (s <= 0.6).all()
    s.sum().backward()
    assert torch.isfinite(p.raw_sigma.grad).all()


def test_inverse_softplus_b_is_the_inverse():
    y = torch.linspace(1e-3, 3, 50, dtype=torch.float64)
    torch.testing.assert_close(softplus_b(inverse_softplus_b(y)), y)


def test_restart_of_a_shared_lobe_from_its_own_expanded_values():
    """assign() with the (expanded) values of a shared-lobe TexelParams keeps them (torch's median of a
    stride-0 tensor is NaN: the constructor must not take it)."""
    T = 5
    p = TexelParams(
        torch.full((T, 3), 0.5),
        torch.full((T, 3), 0.3),
        torch.full((T,), 0.1),
        0.01,
        0.6,
        shared_specular=True,
        ps_max=4.0,
    )
    with torch.no_grad():
        before = [x.clone() for x in p.values()]
        p.assign(*p.values())
    for a, b in zip(before, p.values()):
        torch.testing.assert_close(a, b.detach())
