"""The radiosity level: diffuse interreflection between patches (dissertation 4.2, eq. 4.6).

    B_u = rho_u (E_u + sum_v F_uv B_v)

for every light p and channel c at once, with E the direct irradiance of each patch
(torchrefl.transport.local) and F the form factors (torchrefl.transport.form_factors;
F_uv = fraction of the energy leaving u that reaches v). Per channel this is the linear
system (I - diag(rho_c) F) B_c = rho_c E_c with the P lights as right-hand sides.

Two solvers, chosen by size (method="auto"): a direct LU solve for Q <= direct_max patches, and
the fixed-point (Jacobi) iteration B <- rho (E + F B) with a tolerance and an iteration cap for
larger systems, which works with sparse F. Both are differentiable through an implicit
adjoint: for g = dL/dB, lambda solves (I - rho F)^T lambda = g, then dL/drho = sum_p lambda
(E + F B) and dL/dE = rho lambda, so the backward pass costs one more solve and stores nothing
per iteration.

The iteration converges when rho F has spectral radius < 1. In closed geometry (rows of F
summing to 1) this fails as rho -> 1; `check_conditioning` warns when the bound
max_u rho_u sum_v F_uv is above 1 - 1e-3 and raises FitError at or above 1.
"""

from __future__ import annotations

import warnings

import torch

from torchrefl.errors import FitError


class NearSingularWarning(RuntimeWarning):
    """I - rho F is close to singular: the radiosity solution is extremely sensitive."""


def sparse_operator(M: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """M (dense, or sparse COO) as the interreflection levels keep their form factors and reconstruction, in the fit's
    dtype: dense stays dense; sparse as CSR with int32 indices (12 bytes an entry in float64, 8 in float32, against
    COO's 24 and 20; its products 2-8x faster than float32 COO's on one core, for 18 to 336 columns)."""
    if M.layout == torch.strided:
        return M.to(dtype)
    C = (M.coalesce() if M.layout == torch.sparse_coo else M).to(dtype).to_sparse_csr()
    if C._nnz() >= 2**31:
        return C
    return torch.sparse_csr_tensor(C.crow_indices().int(), C.col_indices().int(), C.values(), C.shape)


def is_sparse(M: torch.Tensor) -> bool:
    """M is a sparse tensor of either layout (COO or CSR)."""
    return M.layout != torch.strided


def _matmul(F: torch.Tensor, X: torch.Tensor) -> torch.Tensor:
    """F (Q, Q) dense, COO or CSR times X (Q, K), in X's dtype (a CSR F multiplies in its own dtype, the fit's)."""
    if F.layout == torch.sparse_csr:
        return (F @ X.to(F.dtype)).to(X.dtype)
    F = F.to(X.dtype)
    return torch.sparse.mm(F, X) if F.is_sparse else F @ X


def _transpose(F: torch.Tensor) -> torch.Tensor:
    if F.layout == torch.sparse_csr:
        return F.t().to_sparse_csr()
    return F.t().coalesce() if F.is_sparse else F.t()


def nonzeros(F: torch.Tensor) -> int:
    """The stored (sparse) or non-zero (dense) entries of F."""
    return int(F._nnz()) if is_sparse(F) else int((F != 0).sum())


def row_sums(F: torch.Tensor) -> torch.Tensor:
    """(Q,) sum_v F_uv."""
    if F.layout == torch.sparse_csr:
        return (F @ torch.ones(F.shape[1], 1, dtype=F.dtype, device=F.device))[:, 0]
    return torch.sparse.sum(F, dim=1).to_dense() if F.is_sparse else F.sum(dim=1)


def check_conditioning(rho: torch.Tensor, F: torch.Tensor, warn_margin: float = 1e-3) -> float:
    """The bound max_c max_u rho_uc sum_v F_uv on the spectral radius of rho F (float).

    Raises FitError when >= 1 (no unique bounded solution: rho = 1 in closed geometry),
    warns NearSingularWarning when within warn_margin of 1.
    """
    bound = float((rho.detach() * row_sums(F.detach()).to(rho.dtype)[:, None]).max())
    if bound >= 1.0:
        raise FitError(
            f"radiosity: I - rho F is singular (max rho * sum_v F_uv = {bound:.6f} >= 1): reflectance 1 in closed "
            "geometry keeps light forever (reflectances must stay below 1)"
        )
    if bound > 1.0 - warn_margin:
        warnings.warn(
            f"radiosity: I - rho F is near singular (max rho * sum_v F_uv = {bound:.6f}); the solution "
            "amplifies errors by up to 1 / (1 - bound)",
            NearSingularWarning,
            stacklevel=3,
        )
    return bound


def _direct(rho, E, F, transpose=False):
    """Solve (I - rho F) X = E (or its transpose) per channel. rho (Q, C), E (Q, C, K) -> (Q, C, K).

    One 2-D LU solve per channel in float64 with contiguous operands: MKL's batched float32 solve
    was seen to fail ("SLASWP parameter 6") and hang on these systems.
    """
    Q, C = rho.shape
    Fd = (F.to_dense() if is_sparse(F) else F).to(torch.float64)
    eye = torch.eye(Q, dtype=torch.float64, device=rho.device)
    out = []
    for c in range(C):
        A = eye - rho[:, c : c + 1].to(torch.float64) * Fd
        if transpose:
            A = A.t()
        out.append(torch.linalg.solve(A.contiguous(), E[:, c, :].to(torch.float64).contiguous()))
    return torch.stack(out, 1).to(E.dtype)


def _iterate(rho, E, F, tol, max_iter, transpose=False):
    """Fixed point X = E + rho F X (or X = E + F^T (rho X)); rho (Q, C), E (Q, C, K).

    The relative tolerance is raised to 8 eps of the working precision at least: in float32 the change
    between iterates stalls at rounding level (~1e-7) and a tighter tolerance could never be met."""
    Q, C, K = E.shape
    Ft = _transpose(F) if transpose else F
    if Ft.layout != torch.sparse_csr:
        Ft = Ft.to(rho.dtype)
    X = E.clone()
    tol = max(float(tol), 8.0 * torch.finfo(E.dtype).eps)
    scale = E.abs().max().clamp_min(1e-30)
    for it in range(max_iter):
        if transpose:
            nxt = E + _matmul(Ft, (rho[:, :, None] * X).reshape(Q, C * K)).reshape(Q, C, K)
        else:
            nxt = E + rho[:, :, None] * _matmul(Ft, X.reshape(Q, C * K)).reshape(Q, C, K)
        delta = (nxt - X).abs().max()
        X = nxt
        if delta <= tol * scale:
            return X, it + 1
    raise FitError(
        f"radiosity: the iterative solver did not reach tolerance {tol} in {max_iter} iterations "
        f"(last change {float(delta / scale):.3g}): Pd near 1 where texels face each other converges slowly; "
        "a larger radiosity.patch_size gives fewer patches, which the direct solver takes"
    )


class _Solve(torch.autograd.Function):
    @staticmethod
    def forward(ctx, rho, E, F, method, tol, max_iter):
        # unknown Y = B / rho... solve for B directly: (I - rho F) B = rho E
        rhs = rho[:, :, None] * E
        if method == "direct":
            B = _direct(rho, rhs, F)
        else:
            B, _ = _iterate(rho, rhs, F, tol, max_iter)
        ctx.save_for_backward(rho, E, B)
        ctx.F, ctx.method, ctx.tol, ctx.max_iter = F, method, tol, max_iter
        return B

    @staticmethod
    def backward(ctx, g):
        rho, E, B = ctx.saved_tensors
        F = ctx.F
        if ctx.method == "direct":
            lam = _direct(rho, g, F, transpose=True)
        else:
            lam, _ = _iterate(rho, g, F, ctx.tol, ctx.max_iter, transpose=True)
        Q, C, K = B.shape
        FB = _matmul(F, B.reshape(Q, C * K)).reshape(Q, C, K)
        d_rho = (lam * (E + FB)).sum(-1)
        d_E = rho[:, :, None] * lam
        return d_rho, d_E, None, None, None, None


def solve_radiosity(
    rho: torch.Tensor,
    E: torch.Tensor,
    F: torch.Tensor,
    *,
    method: str = "auto",
    tol: float = 1e-9,
    max_iter: int = 1000,
    direct_max: int = 3000,
    check: bool = True,
) -> torch.Tensor:
    """Radiosity B (P, Q, C) for reflectance rho (Q, C), direct irradiance E (P, Q, C), form factors F (Q, Q).

    method: 'direct' (dense LU), 'iterative' (fixed point, sparse-friendly) or 'auto'
    (direct when Q <= direct_max). Differentiable in rho and E.
    """
    if rho.dim() != 2 or E.dim() != 3 or E.shape[1:] != rho.shape or F.shape != (rho.shape[0], rho.shape[0]):
        raise FitError(
            f"radiosity: shapes rho {tuple(rho.shape)}, E {tuple(E.shape)}, F {tuple(F.shape)} do not "
            "match rho (Q, C), E (P, Q, C), F (Q, Q)"
        )
    if method not in ("auto", "direct", "iterative"):
        raise FitError(f"radiosity: unknown solver '{method}', expected auto, direct or iterative")
    if check:
        check_conditioning(rho, F)
    if method == "auto":
        method = "direct" if rho.shape[0] <= direct_max else "iterative"
    Et = E.permute(1, 2, 0)  # (Q, C, P)
    B = _Solve.apply(rho, Et, F, method, tol, max_iter)
    return B.permute(2, 0, 1)
