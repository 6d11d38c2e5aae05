"""Which texels an outer iteration of an interreflection level can leave alone (issue 36: cost where it matters).

Two measurements, both against fit.noise_floor_dn (the 8-bit DN below which `auto` leaves interreflection out):
- quiet texels: the indirect light the level predicts on every fitted observation of the texel is below the noise
  floor, so a refit after the first (which only moves the indirect light) has nothing to fit there;
- changed texels: the level's indirect terms (IndirectTerms: per unit Pd, and per unit Ps at a lobe) moved by more
  than the noise floor on some fitted observation since the last re-estimation; the re-estimation's sigma search
  runs again on these only (the others' inputs are those it saw last time).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchrefl.transport.levels.base import IndirectTerms


def _dn_max(light: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(T,) the largest |light| (P, T, 3) of each texel's fitted observations mask (P, T), in 8-bit DN."""
    return (light.abs() * mask[..., None].to(light.dtype)).amax((0, 2)) * 255.0


def quiet_texels(terms: IndirectTerms, pd, ps, sigma, mask: torch.Tensor, floor_dn: float) -> torch.Tensor:
    """(T,) bool texels whose predicted indirect light at (pd, ps, sigma) is below floor_dn on all their fitted
    observations mask (P, T)."""
    light = pd[None] * terms.diffuse + ps[None] * terms.specular(sigma)
    return _dn_max(light, mask.to(light.device)) < floor_dn


@dataclass
class IndirectMemory:
    """The indirect terms a re-estimation saw: diffuse (P, T, 3), specular (P, T, 3) per unit Ps at the lobes sigma
    (T,)."""

    diffuse: torch.Tensor
    specular: torch.Tensor
    sigma: torch.Tensor

    @classmethod
    def of(cls, terms: IndirectTerms, sigma: torch.Tensor) -> IndirectMemory:
        return cls(terms.diffuse, terms.specular(sigma), sigma)

    def changed(self, terms: IndirectTerms, pd, ps, mask: torch.Tensor, floor_dn: float) -> torch.Tensor:
        """(T,) bool texels whose indirect light at Pd, Ps (and the remembered lobes) moves by more than floor_dn on
        a fitted observation mask (P, T) from these terms to `terms`."""
        move = pd[None] * (terms.diffuse - self.diffuse) + ps[None] * (terms.specular(self.sigma) - self.specular)
        return _dn_max(move, mask.to(move.device)) > floor_dn
