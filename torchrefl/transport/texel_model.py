"""A level's model of some texels with the indirect light held fixed (TransportLevel.texel_model), in parts.

    i = Pd (A + H) + Ps (D(theta_h; sigma) B + S(sigma)),   S_o(sigma) = sum over o's entries e of D(theta_e; sigma) w_e

A, B, theta_h: the local model's terms (torchrefl.transport.local); H: the indirect light per unit Pd; S: the indirect
light per unit Ps, which at the photon level is a sum of lobe-weighted entries (the photon cache's specular entries).
Called, a TexelModel predicts as the level's texel_model always did; its parts let the per-texel LM
(torchrefl.fit.fitted_problem) evaluate the model and its Jacobian in closed form at the fitted observations only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import torch

from torchrefl.transport.local import LocalTerms, predict


@dataclass
class SpecularEntries:
    """A specular factor per unit Ps as entries: obs (E,) long, the observation p * n + j (n texels) each entry
    lights; theta_h (E,); weight (E, 3). Observation o's factor is sum of D(theta_h[e]; sigma of its texel) weight[e]
    over its entries."""

    obs: torch.Tensor
    theta_h: torch.Tensor
    weight: torch.Tensor

    @staticmethod
    def empty(dtype: torch.dtype, device=None) -> "SpecularEntries":
        return SpecularEntries(
            torch.zeros(0, dtype=torch.long, device=device),
            torch.zeros(0, dtype=dtype, device=device),
            torch.zeros(0, 3, dtype=dtype, device=device),
        )


@dataclass
class TexelModel:
    """(pd (n, 3), ps (n, C), sigma (n,)) -> (P, n, 3) the images of n texels, each a function of its own parameters.

    local: the local terms of these texels; diffuse (P, n, 3): the indirect light per unit Pd (None: none);
    specular: sigma (n,) -> (P, n, 3) the indirect light per unit Ps (None: none); entries: () -> the same factor as
    SpecularEntries (built on demand; None where the level's factor is not of that form)."""

    local: LocalTerms
    diffuse: Optional[torch.Tensor] = None
    specular: Optional[Callable[[torch.Tensor], torch.Tensor]] = None
    entries: Optional[Callable[[], SpecularEntries]] = None

    @property
    def closed_form(self) -> bool:
        """Whether every part is known in closed form (the specular factor absent or given as entries)."""
        return self.specular is None or self.entries is not None

    def __call__(self, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        out = predict(self.local, pd, ps, sigma)
        if self.diffuse is not None:
            out = out + pd[None] * self.diffuse
        if self.specular is not None:
            out = out + ps[None] * self.specular(sigma)
        return out
