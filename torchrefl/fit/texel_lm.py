"""Levenberg-Marquardt per texel (fit.optimizer: lm).

With the level's indirect light held at the current Pd (TransportLevel.texel_model), each texel's
predicted images depend on its own Pd, Ps and sigma only, so the objective (torchrefl.fit.refine:
robust loss of the 8-bit residuals plus the priors' log pulls) is a sum of independent per-texel
problems of 5 or 7 unknowns. Each iteration takes one Gauss-Newton step per texel on the raw
(unconstrained) tensors, with iteratively reweighted residuals for the robust loss and a damping
lambda of its own: the step is kept where the texel's cost fell (lambda / 3), refused where not
(lambda * 4). The indirect light is re-evaluated at the new Pd before the next iteration. Why not
joint LBFGS steps: docs/results/fold.md. Where the level's model of the texels is a TexelModel in closed form
(every level's), the residuals and the Jacobian are evaluated at the fitted observations only, the Jacobian in
closed form (torchrefl.fit.fitted_problem); a plain model callable gets forward-mode derivatives of its images.
"""

from __future__ import annotations

from typing import Callable

import torch

from torchrefl.core.params import TexelParams, softplus_b
from torchrefl.errors import FitError
from torchrefl.fit.fitted_problem import FittedEntries, FittedProblem, irls_weight, prior_pulls, texel_priors
from torchrefl.fit.refine import Objective, robust_loss
from torchrefl.transport.texel_model import TexelModel

#: the iterations stop once one lowers the total cost by less than this fraction
TOLERANCE = 1e-3
_LAMBDA0, _LAMBDA_MIN, _LAMBDA_MAX = 1e-2, 1e-7, 1e7
#: fitted observations per chunk of the normal equations' sums (bounds their float64 temporaries: ~100 MB at K = 7)
_CHUNK = 1 << 18


class _TexelProblem:
    """The per-texel residuals of an Objective for a frozen-indirect model, as functions of the raw tensors of the
    texels `texels` (n,) long (None: all): model takes and gives their rows only."""

    def __init__(self, params: TexelParams, objective: Objective, model: Callable, texels=None):
        self.params, self.objective, self.model = params, objective, model
        pick = (lambda x, dim=0: x) if texels is None else (lambda x, dim=0: x.index_select(dim, texels))
        self.weight = pick(objective.weight, 1)
        self.intensity = pick(objective.intensity, 1)
        self.mask = self.weight.to(objective.intensity.dtype)[..., None]
        self.priors = texel_priors(objective, texels)

    def residuals(self, raw_pd, raw_ps, raw_sigma) -> tuple[torch.Tensor, torch.Tensor]:
        """(P, n, 3) data residuals in 8-bit DN (0 where not fitted), and (n, m (C + 1)) the m priors' residuals."""
        p = self.params
        pd, ps, sigma = softplus_b(raw_pd), p.ps_of(raw_ps), p.sigma_of(raw_sigma)
        r = (self.model(pd, ps, sigma) - self.intensity) * 255.0 * self.mask
        return r, prior_pulls(self.priors, ps, sigma)

    def cost(self, r: torch.Tensor, pulls: torch.Tensor) -> torch.Tensor:
        """(n,) each texel's cost: its robust losses plus half its squared prior residuals."""
        o = self.objective
        return robust_loss(r, o.loss, o.loss_scale_8bit).sum((0, 2)) + 0.5 * (pulls * pulls).sum(1)

    def normal_equations(self, x: list, columns: list) -> tuple:
        return _normal_equations(self, x, columns)


def levenberg_marquardt(
    params: TexelParams,
    objective: Objective,
    texel_model: Callable[..., Callable],
    iterations: int,
    progress=None,
    train=None,
    skip: torch.Tensor | None = None,
    texels_model: Callable[..., Callable] | None = None,
) -> list[float]:
    """Minimise the objective per texel in place (see the module docstring); returns the objective after each
    iteration. texel_model(pd) -> (pd, ps, sigma) -> (P, T, 3) with the indirect light held at pd; texels_model(pd,
    texels) -> the same model of the texels (n,) long only ((n, 3), ... -> (P, n, 3); TransportLevel.texel_model;
    None, or where it gives None: texel_model's images of them); train: the raw tensors to solve for (default all),
    the others stay fixed. A texel stops being evaluated once it has converged (texel_converged); skip: (T,) bool
    texels not refit at all (they keep their values and count in the objective at them, not in its stop test)."""
    if params.shared_specular or objective.couples_texels:
        raise FitError("fit.optimizer lm: the objective couples texels (a shared lobe or fit.smoothness); use lbfgs")
    raws = [params.raw_pd, params.raw_ps, params.raw_sigma]
    trained = [any(q is t for t in (raws if train is None else train)) for q in raws]
    columns = [(i, j) for i, q in enumerate(raws) if trained[i] for j in range(1 if q.dim() == 1 else q.shape[1])]
    if not columns:
        return []
    T, device = params.num_texels, params.raw_pd.device
    lam = torch.full((T,), _LAMBDA0, dtype=torch.float64, device=device)
    history: list[float] = []
    x = [q.detach().clone() for q in raws]
    if skip is not None:
        skip = skip.to(device)
    active = torch.ones(T, dtype=torch.bool, device=device) if skip is None else ~skip
    refit = active.nonzero()[:, 0]
    cost_all = None  # (T,) each texel's cost at x; a texel no longer evaluated keeps its last
    entries = None  # the refit texels' specular entries at their fitted observations (closed-form models)
    if not bool(active.all()):
        with torch.no_grad():
            full = _TexelProblem(params, objective, texel_model(softplus_b(x[0])))
            cost_all = full.cost(*full.residuals(*x))
    for _ in range(iterations):
        index = active.nonzero()[:, 0]
        if not len(index):
            break
        part = [q.index_select(0, index) for q in x]
        problem, entries = _problem(params, objective, texel_model, texels_model, x, index, entries)
        H, g, r, pulls = problem.normal_equations(part, columns)
        cost = problem.cost(r, pulls)
        if cost_all is None:
            cost_all = cost.clone()
        lam_a = lam.index_select(0, index)
        step = _damped_step(H, g, lam_a, x[0].dtype)
        trial = _stepped(part, step, columns)
        with torch.no_grad():
            new_cost = problem.cost(*problem.residuals(*trial))
        better = new_cost < cost  # NaN compares False: refused
        _accept(x, index, better, trial, part)
        lam_a = torch.where(better, lam_a / 3.0, lam_a * 4.0).clamp(_LAMBDA_MIN, _LAMBDA_MAX)
        lam = lam.index_copy(0, index, lam_a)
        before = float(cost_all.index_select(0, refit).sum())  # the skipped texels' cost is not this fit's
        kept = torch.where(better, new_cost, cost)
        cost_all = cost_all.index_copy(0, index, kept.to(cost_all.dtype))
        total = float(cost_all.sum()) / objective.count
        history.append(total)
        after = float(cost_all.index_select(0, refit).sum())
        typical = after / len(refit)
        active = active.index_put((index,), ~texel_converged(cost, new_cost, better, step, lam_a, typical))
        if progress is not None:
            progress.update(1)
            progress.set_postfix(loss=f"{total:.4g}")
        if not bool(better.any()) or before - after < TOLERANCE * abs(before):
            if progress is not None:  # converged: the bar ends full
                progress.total = len(history)
                progress.refresh()
            break
    with torch.no_grad():
        for q, v in zip(raws, x):
            q.copy_(v)
    if not all(v == v and abs(v) != float("inf") for v in history):
        raise FitError("the lm refinement diverged (loss became NaN or inf)")
    return history


def _problem(params, objective, texel_model, texels_model, x: list, index: torch.Tensor, entries):
    """(the problem of the texels index at the raw values x, the refit's FittedEntries): closed form where the
    level's model of them is a TexelModel in closed form (torchrefl.fit.fitted_problem), else forward-mode
    derivatives of its images. entries: the refit's, built on the first call (whose texels are all the refit's,
    the later ones a subset)."""
    model = None if texels_model is None else texels_model(softplus_b(x[0]), index)
    if isinstance(model, TexelModel) and model.closed_form:
        if entries is None:
            entries = FittedEntries(model, objective.weight, index)
        return FittedProblem(params, objective, model, index, entries), entries
    if model is None:
        model = _texels_of(texel_model(softplus_b(x[0])), params, x, index)
    return _TexelProblem(params, objective, model, index), entries


def _damped_step(H: torch.Tensor, g: torch.Tensor, lam: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """(n, K) the Levenberg-Marquardt step -(H + lam diag(H) + eps)^-1 g of each texel's normal equations H (n, K, K),
    g (n, K) with damping lam (n,); no step where the damped system is singular."""
    diag = torch.diagonal(H, dim1=1, dim2=2)
    A = H + torch.diag_embed(lam[:, None] * diag + 1e-12 * (1.0 + diag.amax(1, keepdim=True)))
    solved, info = torch.linalg.solve_ex(A, g[..., None])
    return -torch.where((info == 0)[:, None], solved[..., 0], 0.0).to(dtype)  # singular: no step


def _accept(x: list, index: torch.Tensor, better: torch.Tensor, trial: list, part: list) -> None:
    """Sets the texels index (n,) of the raw tensors x (in the list, in place) to their trial values where better
    (n,) bool, to part (their values before the step) elsewhere."""
    for i in range(3):
        keep = better.view(-1, *([1] * (x[i].dim() - 1)))
        x[i] = x[i].index_copy(0, index, torch.where(keep, trial[i], part[i]))


def _stepped(x: list, step: torch.Tensor, columns: list) -> list:
    """The raw tensors x moved by step (n, K), its column k on component columns[k]."""
    trial = [q.clone() for q in x]
    for k, (i, j) in enumerate(columns):
        if trial[i].dim() == 1:
            trial[i] = trial[i] + step[:, k]
        else:
            trial[i][:, j] += step[:, k]
    return trial


def _texels_of(model: Callable, params: TexelParams, x: list, index: torch.Tensor) -> Callable:
    """The full model's images of the texels index (n,) long, the other texels at the raw values x."""
    at = [softplus_b(x[0]), params.ps_of(x[1]), params.sigma_of(x[2])]

    def of(*values: torch.Tensor) -> torch.Tensor:
        full = [a.index_put((index,), v) for a, v in zip(at, values)]
        return model(*full).index_select(1, index)

    return of


def texel_converged(
    cost: torch.Tensor,
    new_cost: torch.Tensor,
    better: torch.Tensor,
    step: torch.Tensor,
    lam: torch.Tensor,
    typical: float,
) -> torch.Tensor:
    """(n,) bool texels this iteration left below the fit's own tolerance (TOLERANCE): a step (kept or not) that
    moved no raw component by more than it and changed their cost by less than that fraction of their cost plus
    `typical` (the mean refit texel's cost: a texel fitted exactly has none to be a fraction of); or a refused step at
    the largest damping (no step left to try)."""
    change = (cost - new_cost).abs()
    small = (step.abs().amax(1) <= TOLERANCE) & (change <= TOLERANCE * (cost.abs() + typical))
    return small | (~better & (lam >= _LAMBDA_MAX))


def _normal_equations(problem: _TexelProblem, x: list, columns: list) -> tuple:
    """(T, K, K) J^T W J and (T, K) J^T W r per texel (float64), the Jacobian's columns by forward-mode
    derivatives along each raw component of every texel at once (the texels do not interact); and the residuals
    r, pulls at x (the first derivative's primal). The columns are kept at the fitted observations only (the
    residuals are 0 elsewhere) and the sums run over chunks of them: memory follows the fitted observations, not
    images x texels x K."""
    o = problem.objective
    fitted = problem.weight
    t_idx = fitted.nonzero()[:, 1]  # each fitted observation's texel, in the order r[fitted] lists them
    cols, pcols = [], []
    for i, j in columns:
        tangent = [torch.zeros_like(q) for q in x]
        if tangent[i].dim() == 1:
            tangent[i].fill_(1.0)
        else:
            tangent[i][:, j] = 1.0
        (r, pulls), (jr, jp) = torch.func.jvp(problem.residuals, tuple(x), tuple(tangent))
        cols.append(jr[fitted])  # (N, 3)
        del jr
        pcols.append(jp)
    rf = r[fitted]
    w = irls_weight(rf, o.loss, o.loss_scale_8bit)
    T, K = r.shape[1], len(columns)
    H = torch.zeros((T, K, K), dtype=torch.float64, device=r.device)
    g = torch.zeros((T, K), dtype=torch.float64, device=r.device)
    for a in range(0, len(t_idx), _CHUNK):
        part = slice(a, a + _CHUNK)
        J = torch.stack([c[part] for c in cols], -1).double()  # (n, 3, K)
        wd = w[part].double()
        H.index_add_(0, t_idx[part], torch.einsum("nck,nc,ncl->nkl", J, wd, J))
        g.index_add_(0, t_idx[part], torch.einsum("nck,nc,nc->nk", J, wd, rf[part].double()))
    if pulls.shape[1]:
        Jp = torch.stack(pcols, -1).double()  # (T, n (C + 1), K)
        H = H + torch.einsum("tjk,tjl->tkl", Jp, Jp)
        g = g + torch.einsum("tjk,tj->tk", Jp, pulls.double())
    return H, g, r, pulls
