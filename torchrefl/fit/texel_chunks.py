"""Method I's per-texel stages in chunks of texels, each with only the images that observe it.

A large mesh_views capture (issue 32 item 7: a million atlas texels, 48 images) is mostly pairs that are no
observation: each camera sees a part of the object, so 8 % of the (image, texel) pairs are observations, and the
dense (P, T) temporaries of the local fit's per-texel stages (the closed forms, the sigma search, the lobe
consensus's evaluations, the uncertainty's Jacobian) would not fit. Those stages are texel by texel (a texel's
result depends on its own observations only), so they run here on chunks of texels, each with the images that have
a fitted observation of any of its texels; the others contribute nothing to a texel's sums. The texels are ordered
by the set of images that observe them (texels seen by the same cameras and lights together: in atlas order a
chunk of rows crosses every chart, and so most cameras), and a chunk is a run of that order. The stages that couple
texels (the lobe consensus's neighbour medians, the lobe fill from texels of the same colour or window, the
uncertainty's noise level, the LM's stop test) stay whole on the (T,) maps and see the same values as without
chunks.

The chunks are used when the dense estimate (transport.memory_estimate: FIT_BYTES_PER_OBSERVATION per pair) is
above FREE_SHARE of the memory free now; a chunk then holds at most that share of the free memory (and
CHUNK_PAIRS pairs).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
import torch

from torchrefl.config import Config
from torchrefl.fit.initialise import TexelLobes, texel_lobes
from torchrefl.fit.profile_search import profiled_fit
from torchrefl.fit.texel_jacobian import ChannelInformation
from torchrefl.fit.uncertainty import (
    Evidence,
    ParameterRanges,
    Uncertainty,
    noise_stride,
    texel_evidence,
    uncertainty_of,
)
from torchrefl.transport.local import LocalTerms
from torchrefl.transport.memory_estimate import FIT_BYTES_PER_OBSERVATION, estimate_memory, free_mb
from torchrefl.transport.texel_model import TexelModel

#: the share of the free memory the fit's dense (image, texel) tensors may take before the texels go in chunks
FREE_SHARE = 0.5
#: (image, texel) pairs in one chunk at most (the uncertainty's Jacobian and its float64 copy: ~500 bytes a pair)
CHUNK_PAIRS = 1 << 21
#: texels per block: a chunk is a run of whole blocks
BLOCK = 1024
_MB = 2.0**20


@dataclass(frozen=True)
class TexelChunk:
    """Texels (n,) long and images (m,) long: those with a fitted observation of any of the texels."""

    texels: torch.Tensor
    images: torch.Tensor

    @property
    def pairs(self) -> int:
        return len(self.texels) * len(self.images)


def observed_order(fitted: torch.Tensor) -> torch.Tensor:
    """(T,) long the texels ordered by the images with a fitted observation of them (fitted (P, T) bool): the sets
    of images in lexicographic order (image 0 first), texels with the same set in their own order."""
    rows = fitted.cpu().numpy()
    return torch.from_numpy(np.lexsort(rows[::-1], axis=0)).long() if len(rows) else torch.arange(fitted.shape[1])


def plan_chunks(fitted: torch.Tensor, max_pairs: int, block: int = BLOCK) -> list[TexelChunk]:
    """Chunks covering every texel once, each (texels x its images) within max_pairs where a block allows: runs of
    blocks of `block` texels (fewer where max_pairs / images is fewer) of observed_order, a block joining the chunk
    before it while the union of their images times their texels stays within max_pairs. fitted: (P, T) bool."""
    P, T = fitted.shape
    order = observed_order(fitted)
    block = max(1, min(block, max_pairs // max(P, 1)))
    nb = -(-T // block)
    pad = torch.zeros(P, nb * block, dtype=torch.bool)
    pad[:, :T] = fitted.cpu().index_select(1, order)
    seen = pad.view(P, nb, block).any(2)  # (P, nb)
    chunks, start, images = [], 0, torch.zeros(P, dtype=torch.bool)
    for b in range(nb):
        stop = min(T, (b + 1) * block)
        both = images | seen[:, b]
        if b * block > start and int(both.sum()) * (stop - start) > max_pairs:
            chunks.append(_chunk(order[start : b * block], images))
            start, both = b * block, seen[:, b].clone()
        images = both
    chunks.append(_chunk(order[start:T], images))
    return chunks


def _chunk(texels: torch.Tensor, images: torch.Tensor) -> TexelChunk:
    index = images.nonzero()[:, 0]
    return TexelChunk(texels, index if len(index) else torch.zeros(1, dtype=torch.long))  # one image at least


def texel_chunks(cfg: Config, texels: int, fitted: torch.Tensor, log) -> Optional[list[TexelChunk]]:
    """The chunks of a local fit whose dense estimate exceeds FREE_SHARE of the free memory (None: not needed, not
    applicable: another level, or fit.specular shared / pooled, whose search couples the texels). fitted (P, T)."""
    if cfg.fit.model != "local" or cfg.fit.specular != "texel":
        return None
    P = int(fitted.shape[0])
    dense = estimate_memory(cfg, texels, P, "local").total_mb
    free = free_mb()
    if free is None or dense <= FREE_SHARE * free:
        return None
    max_pairs = max(1, min(CHUNK_PAIRS, int(FREE_SHARE * free * _MB / FIT_BYTES_PER_OBSERVATION)))
    chunks = plan_chunks(fitted, max_pairs)
    pairs = sum(c.pairs for c in chunks)
    log(
        f"memory: the local fit's dense (image, texel) tensors estimated at {dense:.0f} MiB, {free:.0f} MiB free: "
        f"the per-texel stages run in {len(chunks)} chunks of texels with the images that observe them "
        f"({pairs / (P * texels):.1%} of the {P} x {texels} pairs)"
    )
    return chunks


def chunk_terms(terms: LocalTerms, chunk: TexelChunk) -> LocalTerms:
    """The local terms of the chunk's images and texels."""
    return terms.subset(chunk.texels, chunk.images)


def _pick(x: torch.Tensor, chunk: TexelChunk) -> torch.Tensor:
    """x (P, T, ...) at the chunk's images and texels."""
    return x.index_select(1, chunk.texels.to(x.device)).index_select(0, chunk.images.to(x.device))


def _joined(parts: list[torch.Tensor], chunks: list[TexelChunk], dim: int = 0) -> torch.Tensor:
    """The chunks' results parts (each with the chunk's texels along dim) as one tensor over all texels."""
    index = torch.cat([c.texels for c in chunks]).to(parts[0].device)
    joined = torch.cat(parts, dim)
    return joined.index_copy(dim, index, joined)


def chunked_lobes(
    chunks: list[TexelChunk], terms: LocalTerms, intensity, cls, n_spec, fit_mask, **options
) -> TexelLobes:
    """initialise.texel_lobes chunk by chunk (options: its keywords)."""
    parts = [
        texel_lobes(
            chunk_terms(terms, c),
            _pick(intensity, c),
            _pick(cls, c),
            n_spec.index_select(0, c.texels.to(n_spec.device)),
            _pick(fit_mask, c),
            **options,
        )
        for c in chunks
    ]
    fields = TexelLobes.__dataclass_fields__
    joined = {
        k: None if getattr(parts[0], k) is None else _joined([getattr(p, k) for p in parts], chunks) for k in fields
    }
    return TexelLobes(**joined)


def chunked_profile(
    chunks: list[TexelChunk], terms: LocalTerms, intensity, mask, ps_channels: int, ps_max: float
) -> Callable[[torch.Tensor], tuple]:
    """profile_search.profiled_fit chunk by chunk: sigma (T,) or 0-d -> (pd (T, 3), ps (T, C), error (T,))."""
    T = int(intensity.shape[1])

    def evaluate(sigma: torch.Tensor):
        sigma = sigma.expand(T) if sigma.dim() == 0 else sigma
        out = []
        for c in chunks:
            profile = profiled_fit(chunk_terms(terms, c), _pick(intensity, c), _pick(mask, c), ps_channels, ps_max)
            out.append(profile(sigma.index_select(0, c.texels.to(sigma.device))))
        return tuple(_joined(list(x), chunks) for x in zip(*out))

    return evaluate


def chunked_uncertainty(
    chunks: list[TexelChunk],
    terms: LocalTerms,
    pd,
    ps,
    sigma,
    intensity,
    fit_mask,
    lobe_measured,
    ranges: ParameterRanges,
    loss: str,
    loss_scale_8bit: float,
    noise_dn: float | None,
) -> Uncertainty:
    """fit.uncertainty.texel_uncertainty of the local model chunk by chunk: each chunk's information; the noise
    from every noise_stride-th texel over all images, as texel_uncertainty estimates it."""
    per_channel = None  # every texel's ChannelInformation, each chunk's texels filled in as it is done
    for c in chunks:
        t = c.texels.to(pd.device)
        ev = texel_evidence(
            TexelModel(chunk_terms(terms, c)),
            pd[t],
            ps[t],
            sigma[t],
            _pick(intensity, c),
            _pick(fit_mask, c),
            loss,
            loss_scale_8bit,
        )
        if per_channel is None:
            per_channel = ChannelInformation.zeros(ev.per_channel, len(pd))
        per_channel.put(t, ev.per_channel)
        del ev
    noise: Evidence | None = None
    if noise_dn is None:
        T = int(pd.shape[0])
        sub = torch.arange(0, T, noise_stride(T), device=pd.device)
        noise = texel_evidence(
            TexelModel(terms.texels(sub)),
            pd[sub],
            ps[sub],
            sigma[sub],
            intensity.index_select(1, sub),
            fit_mask.index_select(1, sub),
            loss,
            loss_scale_8bit,
        )
    return uncertainty_of(per_channel, noise, lobe_measured, ranges, ps.shape[1], noise_dn)
