"""Radiosity solve: analytic closed sphere, energy balance, solvers agree, gradcheck, near-singular."""

import warnings

import pytest
import torch

from torchrefl.errors import FitError
from torchrefl.transport.radiosity import (
    NearSingularWarning,
    check_conditioning,
    row_sums,
    solve_radiosity,
    sparse_operator,
)


def sphere_interior(Q=40, seed=0):
    """Inside a sphere every patch sees every patch: F_uv = A_v / A_total exactly (F_uu included)."""
    g = torch.Generator().manual_seed(seed)
    A = 0.5 + torch.rand(Q, generator=g, dtype=torch.float64)
    F = (A / A.sum())[None, :].expand(Q, Q).clone()
    return A, F


def random_reciprocal(Q=30, seed=1, leak=0.3):
    """A reciprocal open configuration: A_u F_uv = A_v F_vu, rows summing to < 1."""
    g = torch.Generator().manual_seed(seed)
    A = 0.5 + torch.rand(Q, generator=g, dtype=torch.float64)
    G = torch.rand(Q, Q, generator=g, dtype=torch.float64)
    G = G + G.t()
    G.fill_diagonal_(0)
    F = G / A[:, None]
    F = F / F.sum(1).max() * (1 - leak)
    return A, F


@pytest.mark.parametrize("method", ["direct", "iterative"])
@pytest.mark.parametrize("rho_value", [0.2, 0.8, 0.99])
def test_closed_sphere_matches_rho_e_over_one_minus_rho(method, rho_value):
    A, F = sphere_interior()
    Q = len(A)
    rho = torch.full((Q, 3), rho_value, dtype=torch.float64)
    E = torch.full((2, Q, 3), 1.7, dtype=torch.float64)
    B = solve_radiosity(rho, E, F, method=method, tol=1e-13, max_iter=20000)
    torch.testing.assert_close(B, torch.full_like(B, rho_value * 1.7 / (1 - rho_value)), rtol=1e-8, atol=1e-10)


def test_energy_balance_in_an_open_scene():
    A, F = random_reciprocal()
    Q = len(A)
    g = torch.Generator().manual_seed(3)
    rho = 0.1 + 0.8 * torch.rand(Q, 3, generator=g, dtype=torch.float64)
    E = torch.rand(4, Q, 3, generator=g, dtype=torch.float64)
    B = solve_radiosity(rho, E, F)
    emitted_in = (A[None, :, None] * E).sum(1)  # power of the direct light
    absorbed = (A[None, :, None] * B * (1 / rho - 1)).sum(1)
    escaped = (A[None, :, None] * B * (1 - F.sum(1))[None, :, None]).sum(1)
    torch.testing.assert_close(emitted_in, absorbed + escaped, rtol=1e-10, atol=1e-12)


def test_direct_iterative_and_sparse_agree():
    A, F = random_reciprocal(Q=50)
    F[F < 0.01] = 0
    g = torch.Generator().manual_seed(4)
    rho = 0.1 + 0.85 * torch.rand(50, 3, generator=g, dtype=torch.float64)
    E = torch.rand(3, 50, 3, generator=g, dtype=torch.float64)
    a = solve_radiosity(rho, E, F, method="direct")
    b = solve_radiosity(rho, E, F, method="iterative", tol=1e-13)
    c = solve_radiosity(rho, E, F.to_sparse(), method="iterative", tol=1e-13)
    torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(a, c, rtol=1e-10, atol=1e-12)
    csr = sparse_operator(F.to_sparse(), torch.float64)  # as the levels keep it: CSR in the fit's dtype, int32 indices
    assert csr.layout == torch.sparse_csr and csr.col_indices().dtype == torch.int32
    for method in ("direct", "iterative"):
        torch.testing.assert_close(a, solve_radiosity(rho, E, csr, method=method, tol=1e-13), rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(row_sums(csr), F.sum(1))
    # a float32 fit's solve with its float32 operator: float32 results, within float32's precision of float64's
    d = solve_radiosity(rho.float(), E.float(), sparse_operator(F.to_sparse(), torch.float32), method="iterative")
    assert d.dtype == torch.float32
    torch.testing.assert_close(d.double(), a, rtol=2e-5, atol=1e-6)


def test_a_float64_solve_with_a_float32_operator_is_float64_and_within_float32s_precision():
    """A CSR operator multiplies in its own dtype: a float64 right-hand side with a float32 operator (a float32 fit's
    form factors in a float64 computation) gives float64 results within float32's precision of the exact ones, and
    the iteration converges at its tolerance."""
    A, F = random_reciprocal(Q=50, leak=0.05)
    F[F < 0.005] = 0
    g = torch.Generator().manual_seed(7)
    rho = 0.5 + 0.45 * torch.rand(50, 3, generator=g, dtype=torch.float64)
    E = torch.rand(2, 50, 3, generator=g, dtype=torch.float64)
    exact = solve_radiosity(rho, E, F, method="direct")
    got = solve_radiosity(rho, E, sparse_operator(F.to_sparse(), torch.float32), method="iterative", tol=1e-9)
    assert got.dtype == torch.float64
    torch.testing.assert_close(got, exact, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("method", ["direct", "iterative"])
def test_gradcheck_with_a_csr_operator(method):
    A, F = random_reciprocal(Q=6)
    F[F < 0.02] = 0
    csr = sparse_operator(F.to_sparse(), torch.float64)
    g = torch.Generator().manual_seed(6)
    rho = (0.2 + 0.6 * torch.rand(6, 2, generator=g, dtype=torch.float64)).requires_grad_()
    E = torch.rand(2, 6, 2, generator=g, dtype=torch.float64).requires_grad_()
    f = lambda r, e: solve_radiosity(r, e, csr, method=method, tol=1e-14, max_iter=5000)
    assert torch.autograd.gradcheck(f, (rho, E))


@pytest.mark.parametrize("method", ["direct", "iterative"])
def test_gradcheck(method):
    A, F = random_reciprocal(Q=6)
    g = torch.Generator().manual_seed(5)
    rho = (0.2 + 0.6 * torch.rand(6, 2, generator=g, dtype=torch.float64)).requires_grad_()
    E = torch.rand(2, 6, 2, generator=g, dtype=torch.float64).requires_grad_()
    f = lambda r, e: solve_radiosity(r, e, F, method=method, tol=1e-14, max_iter=5000)
    assert torch.autograd.gradcheck(f, (rho, E))


def test_gradient_matches_autograd_through_a_dense_solve():
    A, F = random_reciprocal(Q=8)
    rho = torch.full((8, 3), 0.6, dtype=torch.float64, requires_grad=True)
    E = torch.rand(2, 8, 3, dtype=torch.float64)
    solve_radiosity(rho, E, F).square().sum().backward()
    ours = rho.grad.clone()
    rho2 = rho.detach().clone().requires_grad_()
    Bs = []
    for c in range(3):
        M = torch.eye(8, dtype=torch.float64) - rho2[:, c : c + 1] * F
        Bs.append(torch.linalg.solve(M, (rho2[:, c : c + 1] * E[:, :, c].t())))
    torch.stack(Bs, -1).square().sum().backward()
    torch.testing.assert_close(ours, rho2.grad)


def test_near_singular_warns_and_singular_raises():
    A, F = sphere_interior(Q=10)
    with pytest.warns(NearSingularWarning):
        check_conditioning(torch.full((10, 3), 0.9999, dtype=torch.float64), F)
    with pytest.raises(FitError, match="singular"):
        solve_radiosity(torch.ones(10, 3, dtype=torch.float64), torch.ones(1, 10, 3, dtype=torch.float64), F)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_conditioning(torch.full((10, 3), 0.9, dtype=torch.float64), F)


def test_rho_near_one_stays_finite_with_finite_gradients():
    A, F = random_reciprocal(Q=10, leak=0.05)
    rho = torch.full((10, 3), 0.999, dtype=torch.float64, requires_grad=True)
    E = torch.ones(1, 10, 3, dtype=torch.float64)
    B = solve_radiosity(rho, E, F)
    assert torch.isfinite(B).all()
    B.sum().backward()
    assert torch.isfinite(rho.grad).all()


def test_shape_errors():
    with pytest.raises(FitError, match="shapes"):
        solve_radiosity(torch.ones(3, 3), torch.ones(1, 4, 3), torch.eye(3))


def test_strided_right_hand_sides_are_solved():
    """A regression: a (P, Q, C) irradiance sliced from a larger tensor reaches the LU solve strided."""
    A, F = random_reciprocal(Q=40)
    rho = torch.full((40, 3), 0.5, dtype=torch.float32)
    big = torch.rand(40, 3, 24, dtype=torch.float32)
    E = big[:, :, ::2].permute(2, 0, 1)  # (12, 40, 3), non-contiguous
    B = solve_radiosity(rho, E, F.float(), method="direct")
    ref = solve_radiosity(rho, E.contiguous(), F.float(), method="iterative", tol=1e-7)
    torch.testing.assert_close(B, ref, rtol=1e-4, atol=1e-5)


def test_float32_iterative_solve_meets_a_tolerance_below_its_precision():
    """In float32 the change between iterates stalls at rounding level: a tolerance of 1e-9 (or the default
    1e-7, right at float32's eps) is met at 8 eps instead of failing after max_iter, forward and backward."""
    A, F = random_reciprocal(Q=60, leak=0.2)
    g = torch.Generator().manual_seed(5)
    rho = 0.5 + 0.45 * torch.rand(60, 3, generator=g, dtype=torch.float64)
    E = torch.rand(4, 60, 3, generator=g, dtype=torch.float64)
    ref = solve_radiosity(rho, E, F, method="direct")
    for tol in (1e-9, 1e-7):
        r32 = rho.float().requires_grad_()
        B = solve_radiosity(r32, E.float(), F.float(), method="iterative", tol=tol, max_iter=500)
        B.sum().backward()
        assert torch.isfinite(r32.grad).all()
        torch.testing.assert_close(B.double(), ref, rtol=2e-5, atol=1e-6)
    with pytest.raises(FitError, match="did not reach tolerance.*radiosity.patch_size"):
        solve_radiosity(rho, E, F, method="iterative", tol=1e-12, max_iter=2)
