"""Texel parameter tensors with constraint-preserving parametrisations.

Pd = softplus_b(raw_pd)   (>= 0; softplus with sharpness b = 20, nearly linear above 0.05)
Ps = ps_max * sigmoid(raw_ps)   (inside (0, ps_max); ps_max = inf uses softplus_b, >= 0)
sigma = sigma_min + (sigma_max - sigma_min) * sigmoid(raw_sigma)   (inside the bounds)
Every map stays inside its constraint for any raw value, so the optimisers need no
projection, and values and gradients stay finite at the bounds.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

SHARPNESS = 20.0
_EDGE = 1e-6
START_MARGIN = 0.01  # initial values keep this fraction of the range away from a sigmoid bound


def softplus_b(x: torch.Tensor) -> torch.Tensor:
    """softplus(b x) / b with b = SHARPNESS."""
    return F.softplus(x, beta=SHARPNESS)


def inverse_softplus_b(y: torch.Tensor) -> torch.Tensor:
    """Inverse of softplus_b for y > 0 (y is floored at 1e-6)."""
    y = y.clamp_min(_EDGE)
    return y + torch.log(-torch.expm1(-SHARPNESS * y)) / SHARPNESS


INIT_FLOOR = 0.01


class TexelParams(nn.Module):
    """pd (T, 3), ps (T, C), sigma (T,) as constrained functions of raw tensors.

    Initial Pd and Ps are floored at init_floor: softplus is flat far below zero, so a parameter
    started at ~0 would barely move; any value down to 0 is still reachable by the optimiser.
    For the same reason initial sigma (and Ps below ps_max) start at least START_MARGIN of their
    range inside the sigmoid's bounds.
    """

    def __init__(
        self,
        pd: torch.Tensor,
        ps: torch.Tensor,
        sigma: torch.Tensor,
        sigma_min: float,
        sigma_max: float,
        init_floor: float = INIT_FLOOR,
        shared_specular: bool = False,
        ps_max: float = float("inf"),
    ):
        super().__init__()
        self.ps_max = float(ps_max)
        self.num_texels = int(pd.shape[0])
        self.shared_specular = shared_specular
        if shared_specular:  # one lobe for the whole object: (1, C) and (1,)
            # contiguous: torch's median of an expanded (stride-0) tensor returns NaN
            ps = ps.contiguous().median(dim=0, keepdim=True).values
            sigma = sigma.contiguous().median(dim=0, keepdim=True).values
        pd = pd.clamp_min(init_floor)
        ps = ps.clamp_min(init_floor)
        self.sigma_min = float(sigma_min)
        self.sigma_max = float(sigma_max)
        span = self.sigma_max - self.sigma_min
        # a start on a bound would pin the parameter there (the sigmoid's slope vanishes): start just inside
        u = ((sigma - self.sigma_min) / span).clamp(START_MARGIN, 1 - START_MARGIN)
        self.raw_pd = nn.Parameter(inverse_softplus_b(pd).detach().clone())
        if self.ps_max == float("inf"):
            self.raw_ps = nn.Parameter(inverse_softplus_b(ps).detach().clone())
        else:
            self.raw_ps = nn.Parameter(torch.logit((ps / self.ps_max).clamp(_EDGE, 1 - START_MARGIN)).detach().clone())
        self.raw_sigma = nn.Parameter(torch.logit(u).detach().clone())

    def pd(self) -> torch.Tensor:
        return softplus_b(self.raw_pd)

    def ps(self) -> torch.Tensor:
        ps = self.ps_of(self.raw_ps)
        return ps.expand(self.num_texels, -1) if self.shared_specular else ps

    def sigma(self) -> torch.Tensor:
        sigma = self.sigma_of(self.raw_sigma)
        return sigma.expand(self.num_texels) if self.shared_specular else sigma

    def ps_of(self, raw_ps: torch.Tensor) -> torch.Tensor:
        """Ps for raw values raw_ps (this module's bounds, not its tensors)."""
        return softplus_b(raw_ps) if self.ps_max == float("inf") else self.ps_max * torch.sigmoid(raw_ps)

    def sigma_of(self, raw_sigma: torch.Tensor) -> torch.Tensor:
        """sigma for raw values raw_sigma (this module's bounds, not its tensors)."""
        return self.sigma_min + (self.sigma_max - self.sigma_min) * torch.sigmoid(raw_sigma)

    def values(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.pd(), self.ps(), self.sigma()

    def assign(self, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor) -> None:
        """Restart from new values (transformed as in __init__), in place."""
        fresh = TexelParams(
            pd, ps, sigma, self.sigma_min, self.sigma_max, shared_specular=self.shared_specular, ps_max=self.ps_max
        )
        with torch.no_grad():
            for name, value in fresh.named_parameters():
                getattr(self, name).copy_(value.to(getattr(self, name)))
