"""One lobe per material for texels that see no highlight and have no measured texel of their colour, fitted to the
light they reflect off the object's other surfaces.

A concave object's texel without a direct highlight still mirrors the glossy surfaces facing it: its specular
reflection of indirect light carries its lobe, too faintly per texel to fit one (on the fold's lower plate 1.9-4.9 DN
per fitted observation; a per-texel fit scattered, docs/results/fold.md) but over a whole material well. Such texels
join the grid neighbours of their colour into clusters (the log colour test of torchrefl.fit.material_fill, so that
a material's smooth variation stays one cluster and a border between materials splits two), and each cluster takes
the one lobe (Ps, sigma) that best fits all its texels' observations with the level's indirect light, each texel
keeping its own Pd: torchrefl.fit.profile_search's profiled sums added over the cluster, on a sigma grid refined by
a parabola through the best grid value and its neighbours.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from torchrefl.core.texel_neighbours import TexelNeighbours
from torchrefl.fit.material_fill import COLOUR_FLOOR, COLOUR_TOLERANCE

#: the fewest texels one lobe is fitted to (a smaller cluster keeps its lobe)
MIN_CLUSTER = 50


def colour_clusters(neighbours: TexelNeighbours, pd: torch.Tensor, members: torch.Tensor) -> np.ndarray:
    """(T,) int64 cluster of each texel: the members (T,) bool joined to their 4-neighbours on the surface
    (neighbours.pairs(), the Surface's: across an atlas's seams) of their colour (largest channel difference of
    log(Pd + COLOUR_FLOOR) <= COLOUR_TOLERANCE); clusters of at least MIN_CLUSTER texels numbered 0.., -1 for the
    rest and for texels that are not members."""
    T = len(members)
    m = members.cpu().numpy()
    pairs = neighbours.pairs()
    colour = np.log(pd.detach().cpu().double().numpy().clip(0, None) + COLOUR_FLOOR)
    i, j = pairs[:, 0], pairs[:, 1]
    joined = m[i] & m[j] & (np.abs(colour[i] - colour[j]).max(-1) <= COLOUR_TOLERANCE)
    graph = coo_matrix((np.ones(int(joined.sum())), (i[joined], j[joined])), shape=(T, T))
    _, label = connected_components(graph, directed=False)
    big = np.bincount(label[m], minlength=T) >= MIN_CLUSTER
    number = np.full(T, -1)
    number[big] = np.arange(int(big.sum()))
    return np.where(m, number[label], -1)


def cluster_lobes(
    parts: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]],
    cluster: np.ndarray,
    sigmas: torch.Tensor,
    ps_channels: int,
    ps_max: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(ps (K, C), sigma (K,), determined (K,) bool): the lobe of each of the K clusters (cluster (T,) from
    colour_clusters); a cluster whose observations carry no specular light at any sigma is not determined.

    parts(sigma 0-d) -> (uu, uv, vv) each (T, 3): per texel and channel the profiled sums at that sigma with Pd
    eliminated (profile_search's _Profile.parts); sigmas (S,) a geometric grid of at least 3 values."""
    if len(sigmas) < 3:
        raise ValueError(f"cluster_lobes: the sigma grid needs at least 3 values, got {len(sigmas)}")
    K = int(cluster.max()) + 1
    of = torch.from_numpy(cluster)
    inside = of >= 0
    errors, values, signal = [], [], 0.0
    for s in sigmas:
        uu, uv, vv = (torch.zeros(K, 3, dtype=x.dtype).index_add_(0, of[inside], x[inside]) for x in parts(s))
        num, den = (uv.sum(-1, keepdim=True), vv.sum(-1, keepdim=True)) if ps_channels == 1 else (uv, vv)
        ps = torch.where(den > 0, num / den.clamp_min(1e-30), torch.zeros_like(num)).clamp(0, ps_max)
        full = ps.expand_as(uv)
        errors.append((uu - 2 * full * uv + full * full * vv).sum(-1))
        values.append(ps)
        signal = signal + vv.sum(-1)
    err, ps_grid = torch.stack(errors, 1), torch.stack(values, 1)  # (K, S), (K, S, C)
    best = err.argmin(1)
    mid = best.clamp(1, len(sigmas) - 2)
    rows = torch.arange(K)
    e0, e1, e2 = err[rows, mid - 1], err[rows, mid], err[rows, mid + 1]
    curve = e0 - 2 * e1 + e2
    step = torch.where(curve > 0, 0.5 * (e0 - e2) / curve.clamp_min(1e-30), torch.zeros_like(curve)).clamp(-1, 1)
    step = torch.where(best == mid, step, (best - mid).to(step.dtype))  # at an end of the grid: that end
    log_grid = sigmas.log().to(err.dtype)
    sigma = (log_grid[mid] + step * (log_grid[1] - log_grid[0])).exp()
    lo, hi = torch.where(step < 0, mid - 1, mid), torch.where(step < 0, mid, mid + 1)
    frac = torch.where(step < 0, step + 1, step)[:, None]
    return ps_grid[rows, lo] * (1 - frac) + ps_grid[rows, hi] * frac, sigma, signal > 0
