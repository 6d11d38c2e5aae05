"""The photon tracer's per-texel material (TexelMaterial: the current Pd, Ps, sigma) and the float32 tables
one trace scatters with (ScatterTables: component probabilities, roulette survivals and weights, lobe
constants), built once per trace by torchrefl.transport.photon_trace.PhotonTracer.trace.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.lobe_sampling import lobe_constants, specular_probability


@dataclass
class TexelMaterial:
    """Current reflectance of every texel, for scattering: pd (T, 3), ps (T, 3), sigma (T,) float64."""

    pd: np.ndarray
    ps: np.ndarray
    sigma: np.ndarray

    @classmethod
    def from_tensors(cls, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor) -> "TexelMaterial":
        T = pd.shape[0]
        as64 = lambda x: x.detach().cpu().double().numpy()
        return cls(as64(pd), np.ascontiguousarray(np.broadcast_to(as64(ps), (T, 3))), as64(sigma))


@dataclass
class ScatterTables:
    """Per-texel float32 tables of one trace, from a TexelMaterial (vectors component-major, (3, T)):
    q (T,) specular sampling probability; ps (3, T), ps_max (T,); sigma (T,) (>= brdf.SIGMA_EPS), truncation,
    ratio_scale (T,) (lobe_constants); for the diffuse branch with and without roulette, (survival (T,),
    weight Pd / (1 - q) / survival (3, T), per-unit-Pd weight 1 / (1 - q) / survival (T,)), the weights zero
    where the survival is zero (a texel that reflects nothing diffusely).

    q is rounded up to the grid of the float32 uniforms (multiples of 2^-24) that choose the component, so
    that P(u < q) is exactly q and every weight divides by the probability actually used: a texel whose Ps is
    tiny but positive is sampled specularly with probability >= 2^-24 (never a denormal q: no overflow),
    and one whose Pd is below ~6e-8 of its Ps is never sampled diffusely (its diffuse part, and its
    per-unit-Pd weight, are then dropped: at most that fraction of its reflection)."""

    q: np.ndarray
    ps: np.ndarray
    ps_max: np.ndarray
    sigma: np.ndarray
    truncation: np.ndarray
    ratio_scale: np.ndarray
    diffuse_roulette: tuple
    diffuse_first: tuple

    @classmethod
    def build(cls, lobe: str | None, mat: TexelMaterial) -> "ScatterTables":
        f32 = lambda x: np.ascontiguousarray(x, dtype=np.float32)
        q = np.ceil(specular_probability(lobe, mat.pd, mat.ps) * 2.0**24) / 2.0**24
        rest = 1.0 - q
        k = np.where(rest > 0, 1.0 / np.where(rest > 0, rest, 1.0), 0.0)
        w = mat.pd * k[:, None]
        top = w.max(-1)

        def branch(survival):
            inv = np.where(survival > 0, 1.0 / np.where(survival > 0, survival, 1.0), 0.0)
            return f32(survival), f32((w * inv[:, None]).T), f32(k * inv)

        sigma = np.maximum(mat.sigma, brdf_mod.SIGMA_EPS)
        trunc, ratio = lobe_constants(lobe, sigma) if lobe is not None else (np.ones_like(sigma), np.zeros_like(sigma))
        return cls(
            f32(q),
            f32(mat.ps.T),
            f32(mat.ps.max(-1)),
            f32(sigma),
            f32(trunc),
            f32(ratio),
            branch(np.minimum(0.95, top)),
            branch((top > 0).astype(np.float64)),
        )

    def diffuse(self, roulette: bool) -> tuple:
        return self.diffuse_roulette if roulette else self.diffuse_first
