"""The Jacobian of texels' images in their own parameters theta = (Pd (3), Ps (C), sigma), K = 4 + C, in 8-bit DN
per parameter unit, and the two products the uncertainty needs of it: the per-channel information sum_p w J J^T and
the quadratic forms J^T Cov J (leverages).

A TexelModel (torchrefl.transport.texel_model) is linear in Pd and Ps, and its channel c depends on Pd_c, Ps_c (Ps
where C = 1) and sigma only:

    d i_c / d Pd_c = A_c + H_c,   d i_c / d Ps_c = D B_c + S_c(sigma),   d i_c / d sigma = Ps_c (D' B_c + S'_c(sigma))

(D = D(theta_h; sigma), D' its derivative in sigma, torchrefl.core.brdf.specular_lobe_dsigma; S' one forward-mode
pass of the specular factor alone). ChannelJacobian keeps those three columns per channel: one pass over the
(P, T, 3) terms instead of K forward-mode passes of the whole model, and products over 3 columns instead of K. Any
other model (P, T, 3) of its texels' own parameters gets DenseJacobian, by forward-mode passes (jacobian).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Union

import torch

from torchrefl.core.brdf import specular_lobe_dsigma
from torchrefl.transport.texel_model import TexelModel

#: parameter components whose tangents vmap batches at once: the batched model's temporaries grow with it (the photon
#: level's specular entries times the batch: 2.9 GB over the fit's memory on the full fold at all 7 at once)
JACOBIAN_CHUNK = 2


@dataclass
class ChannelInformation:
    """Per channel c the information sum_p w J J^T (at unit noise) over the components columns[c] of K, the only
    ones channel c depends on: values (3, T, m, m) float64, columns (3, m) long; num_params K."""

    values: torch.Tensor
    columns: torch.Tensor
    num_params: int

    @staticmethod
    def zeros(like: "ChannelInformation", texels: int) -> "ChannelInformation":
        """like's structure for `texels` texels, all zero (to be filled with put)."""
        values = like.values.new_zeros(3, texels, *like.values.shape[2:])
        return ChannelInformation(values, like.columns, like.num_params)

    def put(self, index: torch.Tensor, part: "ChannelInformation") -> None:
        """Set the texels index (n,) long to part's n texels."""
        self.values.index_copy_(1, index, part.values)

    def texels(self, index) -> "ChannelInformation":
        """The information of the texels index (a slice or (n,) long) only."""
        return ChannelInformation(self.values[:, index], self.columns, self.num_params)

    def scaled(self, noise_dn: torch.Tensor) -> torch.Tensor:
        """(T, K, K) float64 the information at noise_dn (3,) per channel in DN: sum over c of block c / s_c^2."""
        K, T, m = self.num_params, self.values.shape[1], self.values.shape[-1]
        cols = self.columns.to(self.values.device)
        flat = (cols[:, :, None] * K + cols[:, None, :]).reshape(-1)  # (3 m m,) into the flattened K x K
        scaled = self.values / noise_dn.to(self.values).square()[:, None, None, None]
        out = self.values.new_zeros(T, K * K)
        out.index_add_(1, flat, scaled.permute(1, 0, 2, 3).reshape(T, 3 * m * m))
        return out.view(T, K, K)


@dataclass
class DenseJacobian:
    """values (P, T, 3, K): d(255 i_ptc) / d theta_tk of every parameter component."""

    values: torch.Tensor

    def texels(self, index) -> "DenseJacobian":
        """The Jacobian of the texels index (a slice or (n,) long) only."""
        return DenseJacobian(self.values[:, index])

    def dense(self) -> torch.Tensor:
        """(P, T, 3, K) the values."""
        return self.values

    def information(self, weight: torch.Tensor) -> ChannelInformation:
        """The ChannelInformation at the observations' weights (P, T, 3), over all K components. Summed in float64:
        float32 sums leave a block whose parameters are nearly collinear (a strong lobe's Ps and sigma) indefinite
        by rounding, and its Cholesky factorisation fails."""
        J = self.values.double()
        K = J.shape[-1]
        columns = torch.arange(K).expand(3, K)
        return ChannelInformation(torch.einsum("ptck,ptc,ptcl->ctkl", J, weight.double(), J), columns, K)

    def quadratic(self, cov: torch.Tensor) -> torch.Tensor:
        """(P, T, 3) J^T cov J per observation and channel for cov (T, K, K), in J's dtype."""
        return torch.einsum("ptck,tkl,ptcl->ptc", self.values, cov.to(self.values.dtype), self.values)


@dataclass
class ChannelJacobian:
    """values (3, 3, P, T): values[c, i] the derivatives of 255 i_c along the i-th of (Pd_c, Ps_c (Ps where C = 1),
    sigma), the only components channel c depends on (channel-major: each product runs over whole (P, T) planes);
    ps_channels C."""

    values: torch.Tensor
    ps_channels: int

    @property
    def num_params(self) -> int:
        return 4 + self.ps_channels

    def columns(self, c: int) -> list[int]:
        """The components (of K) channel c's three columns are the derivatives along."""
        return [c, 3 + (c if self.ps_channels == 3 else 0), 3 + self.ps_channels]

    def texels(self, index) -> "ChannelJacobian":
        """The Jacobian of the texels index (a slice or (n,) long) only."""
        return ChannelJacobian(self.values[..., index], self.ps_channels)

    def dense(self) -> torch.Tensor:
        """(P, T, 3, K) every component's derivative (zeros where a channel does not depend on it)."""
        P, T = self.values.shape[2:]
        out = self.values.new_zeros(P, T, 3, self.num_params)
        for c in range(3):
            out[:, :, c, self.columns(c)] = self.values[c].permute(1, 2, 0)
        return out

    def information(self, weight: torch.Tensor) -> ChannelInformation:
        """DenseJacobian.information over each channel's three columns (the six distinct products, in float64)."""
        P, T = self.values.shape[2:]
        blocks = torch.zeros(3, 3, 3, T, dtype=torch.float64, device=self.values.device)
        weight = weight.double().permute(0, 2, 1)  # (P, 3, T)
        for p in range(P):  # one image at a time: its (3, 3, T) planes stay in cache (2.6x faster than whole sums)
            v = self.values[:, :, p].double()
            vw = v * weight[p, :, None]
            for i in range(3):
                for j in range(i, 3):
                    blocks[:, i, j].addcmul_(vw[:, i], v[:, j])
        for i in range(3):
            for j in range(i + 1, 3):
                blocks[:, j, i] = blocks[:, i, j]
        columns = torch.tensor([self.columns(c) for c in range(3)])
        return ChannelInformation(blocks.permute(0, 3, 1, 2), columns, self.num_params)

    def quadratic(self, cov: torch.Tensor) -> torch.Tensor:
        """DenseJacobian.quadratic, from each channel's three columns and its 3 x 3 block of cov."""
        out = []
        for c in range(3):
            cols = torch.tensor(self.columns(c), device=cov.device)
            block = cov[:, cols[:, None], cols[None, :]].to(self.values.dtype)  # (T, 3, 3)
            out.append(torch.einsum("ipt,tij,jpt->pt", self.values[c], block, self.values[c]))
        return torch.stack(out, -1)


Jacobian = Union[DenseJacobian, ChannelJacobian]


def texel_model_jacobian(model: TexelModel, ps: torch.Tensor, sigma: torch.Tensor) -> ChannelJacobian:
    """The ChannelJacobian of a TexelModel of n texels at ps (n, C), sigma (n,) (it does not depend on Pd)."""
    local = model.local
    sigma = sigma.detach().contiguous()  # a shared lobe comes expanded (stride 0)
    lobe, dlobe = specular_lobe_dsigma(local.brdf, local.theta_h, sigma[None], local.spread)  # (P, n)
    a = local.diffuse if model.diffuse is None else local.diffuse + model.diffuse
    B = local.specular.permute(2, 0, 1)  # (3, P, n)
    P, n = lobe.shape
    values = torch.empty(3, 3, P, n, dtype=a.dtype, device=a.device)
    torch.mul(a.permute(2, 0, 1), 255.0, out=values[:, 0])
    torch.mul(B, lobe * 255.0, out=values[:, 1])
    torch.mul(B, dlobe * 255.0, out=values[:, 2])
    if model.specular is not None:
        S, dS = torch.func.jvp(model.specular, (sigma,), (torch.ones_like(sigma),))
        values[:, 1] += S.permute(2, 0, 1) * 255.0
        values[:, 2] += dS.permute(2, 0, 1) * 255.0
    values[:, 2] *= ps.detach().t()[:, None]  # (C, 1, n) broadcast over the channels where C = 1
    return ChannelJacobian(values, int(ps.shape[1]))


def dense_jacobian(model: Callable, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor) -> DenseJacobian:
    """The DenseJacobian of model (pd (T, 3), ps (T, C), sigma (T,)) -> (P, T, 3), each texel's images a function
    of its own parameters: forward-mode derivatives along each of the K components of every texel at once, the K
    tangents batched by vmap JACOBIAN_CHUNK at a time (one jvp each where the model has an operation vmap does not
    batch)."""
    x = tuple(q.detach().contiguous() for q in (pd, ps, sigma))  # a shared lobe comes expanded (stride 0)
    widths = [q.shape[1] if q.dim() == 2 else 1 for q in x]
    eye = torch.eye(sum(widths), dtype=pd.dtype, device=pd.device)
    tangents, at = [], 0
    for q, n in zip(x, widths):
        block = eye[:, at : at + n]  # (K, n): the tangent of each column on this tensor
        tangents.append((block[:, None, :] if q.dim() == 2 else block[:, None, 0]).expand(-1, *q.shape))
        at += n
    column = lambda *t: torch.func.jvp(model, x, t)[1]
    try:
        cols = torch.func.vmap(column, chunk_size=JACOBIAN_CHUNK)(*tangents)  # (K, P, T, 3)
    except (RuntimeError, NotImplementedError):  # an operation without a batching rule: one jvp per column
        cols = torch.stack([column(*(t[k] for t in tangents)) for k in range(len(eye))])
    return DenseJacobian(cols.movedim(0, -1) * 255.0)


def jacobian(model: Callable, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor) -> Jacobian:
    """d(255 model) / d theta at (pd, ps, sigma): in closed form for a TexelModel, by forward-mode passes else."""
    if isinstance(model, TexelModel):
        return texel_model_jacobian(model, ps, sigma)
    return dense_jacobian(model, pd, ps, sigma)
