"""Autograd refinement of the texel parameter tensors (LBFGS or Adam).

Objective (per fitted observation, residuals in 8-bit digital numbers of the sensor range):
    mean over (p, t, c) of rho(255 * (i_hat - i))
  + sum over priors (mask, Ps0, sigma0, weight) of weight * mean over the masked texels of
        |ln(Ps + eps) - ln(Ps0 + eps)|^2 + ln(sigma / sigma0)^2
  + smoothness * mean over grid-neighbour pairs of the same two differences,
with rho the robust loss (l2, huber, cauchy) at scale `loss_scale_8bit`. Priors pull texels
without specular evidence towards their interpolated lobe, and (fit.pooling) every texel
towards the object's shared lobe.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import torch

from torchrefl.core.params import TexelParams
from torchrefl.core.texel_neighbours import TexelNeighbours
from torchrefl.errors import FitError

_LOG_EPS = 1e-3


def robust_loss(r: torch.Tensor, kind: str, scale: float) -> torch.Tensor:
    """Elementwise rho(r) for residuals r (any shape); all equal r^2/2 near 0."""
    if kind == "l2":
        return 0.5 * r * r
    if kind == "huber":
        a = r.abs()
        return torch.where(a <= scale, 0.5 * r * r, scale * (a - 0.5 * scale))
    if kind == "cauchy":
        return 0.5 * scale * scale * torch.log1p((r / scale) ** 2)
    raise FitError(f"fit.loss: unknown robust loss '{kind}', expected l2, huber or cauchy")


@dataclass
class Prior:
    """Pull the texels in mask (T,) towards ps (T, C) and sigma (T,) with this weight."""

    mask: torch.Tensor
    ps: torch.Tensor
    sigma: torch.Tensor
    weight: float


def _pull(prior: Prior, ps: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """(masked texels,) the prior's squared log differences of Ps (summed over channels) and sigma."""
    m = prior.mask
    d_ps = torch.log(ps[m] + _LOG_EPS) - torch.log(prior.ps[m] + _LOG_EPS)
    return (d_ps**2).sum(-1) + torch.log(sigma[m] / prior.sigma[m]) ** 2


@dataclass
class Objective:
    """Everything the objective needs besides the parameters.

    predict: callable (pd, ps, sigma) -> (P, T, 3) predicted intensities.
    intensity: (P, T, 3) measured; weight: (P, T) bool observations that are fitted.
    priors: list of Prior; neighbours: (E, 2) texel index pairs or None.
    """

    predict: Callable
    intensity: torch.Tensor
    weight: torch.Tensor
    loss: str = "huber"
    loss_scale_8bit: float = 3.0
    priors: list = field(default_factory=list)
    smoothness: float = 0.0
    neighbours: Optional[torch.Tensor] = None

    def __post_init__(self):
        self._w = self.weight.to(self.intensity.dtype)[..., None]
        self._count = float(self.weight.sum()) * self.intensity.shape[-1]
        if self._count == 0:
            raise FitError(
                "nothing to fit: the objective's observation mask selects no observation (the capture's "
                "loader and fit.fit_observations.require_fit_observations say which filter removed them)"
            )

    @property
    def couples_texels(self) -> bool:
        """Whether the smoothness term ties neighbouring texels' parameters together."""
        return self.smoothness > 0 and self.neighbours is not None and len(self.neighbours) > 0

    def per_texel(self, params: TexelParams) -> torch.Tensor:
        """(T,) each texel's share of the objective without the smoothness term: its observations' robust loss and
        its priors."""
        pd, ps, sigma = params.values()
        out = self._data_loss(pd, ps, sigma).sum((0, 2)) / self._count
        for prior in self.active_priors():
            out = out.index_add(
                0, prior.mask.nonzero()[:, 0], prior.weight * _pull(prior, ps, sigma) / int(prior.mask.sum())
            )
        return out

    @property
    def count(self) -> float:
        """The number of fitted observation channels: the data term is the sum of their robust losses over it."""
        return self._count

    def active_priors(self) -> list:
        """The priors that pull (a positive weight on at least one texel)."""
        return [p for p in self.priors if p.weight > 0 and bool(p.mask.any())]

    def _data_loss(self, pd, ps, sigma) -> torch.Tensor:
        """(P, T, 3) the robust loss of each fitted observation's 8-bit residual (0 where not fitted)."""
        r = (self.predict(pd, ps, sigma) - self.intensity) * 255.0
        return robust_loss(r, self.loss, self.loss_scale_8bit) * self._w

    def __call__(self, params: TexelParams) -> torch.Tensor:
        pd, ps, sigma = params.values()
        total = self._data_loss(pd, ps, sigma).sum() / self._count
        for prior in self.active_priors():
            total = total + prior.weight * _pull(prior, ps, sigma).mean()
        if self.couples_texels:
            i, j = self.neighbours[:, 0], self.neighbours[:, 1]
            lp = torch.log(ps + _LOG_EPS)
            ls = torch.log(sigma)
            # index_select: a deterministic backward (see transport.photon_level.indirect_radiance)
            dp = lp.index_select(0, i) - lp.index_select(0, j)
            ds = ls.index_select(0, i) - ls.index_select(0, j)
            total = total + self.smoothness * ((dp**2).sum(-1) + ds**2).mean()
        return total


def refine(
    params: TexelParams,
    objective: Objective,
    optimizer: str = "lbfgs",
    iterations: int = 60,
    learning_rate: float = 0.05,
    progress=None,
    train=None,
) -> list[float]:
    """Minimise the objective in place; returns the loss history (one value per iteration, and the loss after the
    guard below when it restored texels).

    train: the raw tensors to optimise (default all of params); the others stay fixed.
    Guard: a texel whose own share of the objective (Objective.per_texel) ended higher than it started gets its
    start back. Each texel's share depends on its own parameters (at the interreflection levels also, weakly, on
    the emitters' Pd), so a rise is the joint step's doing, not the texel's data: one shared line search over all
    texels moved a few of them far off (Pd 9.5 against 0.70 in one channel on the default scene) and the robust
    loss's bounded gradient did not bring them back. Off when smoothness couples neighbours.
    """
    history: list[float] = []
    train = list(params.parameters()) if train is None else list(train)
    frozen = [q for q in params.parameters() if all(q is not t for t in train) and q.requires_grad]
    for q in frozen:
        q.requires_grad_(False)
    guard = not objective.couples_texels and not params.shared_specular and optimizer != "none" and iterations > 0
    if guard:
        with torch.no_grad():
            before = objective.per_texel(params)
            start = [q.detach().clone() for q in params.parameters()]
    try:
        _minimise(params, objective, optimizer, iterations, learning_rate, progress, train, history)
    finally:
        for q in frozen:
            q.requires_grad_(True)
    if guard:
        with torch.no_grad():
            worse = objective.per_texel(params) > before
            if bool(worse.any()):
                for q, q0 in zip(params.parameters(), start):
                    q.copy_(torch.where(worse.view(-1, *([1] * (q.dim() - 1))), q0, q))
                history.append(float(objective(params)))
    return history


def _minimise(params, objective, optimizer, iterations, learning_rate, progress, train, history) -> list[float]:
    if optimizer == "none" or iterations == 0:
        with torch.no_grad():
            history.append(float(objective(params)))
        return history
    if optimizer == "lbfgs":
        opt = torch.optim.LBFGS(
            train,
            lr=1.0,
            max_iter=iterations,
            max_eval=int(iterations * 1.5),
            history_size=20,
            tolerance_grad=1e-10,
            tolerance_change=1e-12,
            line_search_fn="strong_wolfe",
        )

        def closure():
            opt.zero_grad()
            loss = objective(params)
            loss.backward()
            history.append(float(loss.detach()))
            if progress is not None:
                progress.update(1)
                progress.set_postfix(loss=f"{history[-1]:.4g}")
            return loss

        opt.step(closure)
    elif optimizer == "adam":
        opt = torch.optim.Adam(train, lr=learning_rate)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=iterations, eta_min=learning_rate * 0.02)
        for _ in range(iterations):
            opt.zero_grad()
            loss = objective(params)
            loss.backward()
            opt.step()
            sched.step()
            history.append(float(loss.detach()))
            if progress is not None:
                progress.update(1)
                progress.set_postfix(loss=f"{float(loss):.4g}")
    else:
        raise FitError(f"fit.optimizer: unknown optimiser '{optimizer}', expected lbfgs, adam or none")
    if not all(map(lambda v: v == v and abs(v) != float("inf"), history)):
        raise FitError(f"the {optimizer} refinement diverged (loss became NaN or inf)")
    return history


def neighbour_pairs(neighbours: TexelNeighbours) -> torch.Tensor:
    """(E, 2) pairs of adjacent texels on the surface, each once (neighbours.pairs(): on a grid the right and down
    neighbours; on an atlas across seams too)."""
    return torch.from_numpy(neighbours.pairs())
