"""Interreflection for synthetic scenes: Monte Carlo path tracing with Embree (the renderer's truth).

The object sits in a dark room lit only by point lights; rays that escape carry nothing, and a
point light is never hit by a sampled ray, so the light reflected by a surface point x0 towards
the camera is direct light (computed elsewhere, analytically with a shadow ray) plus

    L_ind(x0, v) = sum over paths x0 -> y1 -> y2 -> ... of  T_k * g(y_k; l_k, wo_k) * Y / C_k^2 * vis_k,

one next-event (shadow-ray) term per path vertex y_k, where T_k is the product of g/pdf of the
sampled directions before y_k (and of the Russian-roulette divisions), g = f * cos the
cosine-weighted BRDF of torchrefl.core.brdf and C_k the distance from y_k to the light.

Sampling at every vertex is a one-sample mixture: with probability q = mean(Ps) / (mean(Pd) + mean(Ps))
the specular lobe (Torrance-Sparrow theta_h Gaussian or Ward), otherwise cosine-weighted; the
weight uses the mixture pdf (1 - q) cos/pi + q p_lobe, so the estimator is unbiased for any q.
The first bounce uses randomised QMC (a scrambled Sobol set with a random toroidal shift, unbiased):
per origin, or per group of origins that are averaged afterwards (a texel's sub-samples, which then share
one stratified set: torchrefl.core.rqmc.grouped_points); later bounces use independent uniforms (stratifying the
second bounce too, with 6-dimensional points, measured no better). At least
`min_bounces` bounces are traced, then Russian roulette with survival min(0.95, max_c T).

Paths do not depend on the light (sampling uses only the BRDF), so one set of paths serves every
light: `trace` builds the vertices once, `shade` adds next-event estimation per light. All work is
vectorised over paths; the only Python loops run over bounce depth, lights and fixed-size chunks.
Deterministic in `seed` (random numbers are keyed by seed and chunk index, never by thread).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.lobe_sampling import LOBES, row_dot, sample_mixture
from torchrefl.core.point_light import point_light
from torchrefl.core.rays import RayTracer
from torchrefl.core.rqmc import grouped_points
from torchrefl.core.threads import thread_map
from torchrefl.errors import GeometryError


def _t(x) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float64))


@dataclass
class PathVertices:
    """Path vertices y_k (k >= 1) of one chunk of origins: origin (V,) index of the path's origin in the
    chunk; points, normals, wo (V, 3) (wo towards the previous vertex); pd, ps (V, 3), sigma (V,);
    throughput (V, 3)."""

    origin: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    wo: np.ndarray
    pd: np.ndarray
    ps: np.ndarray
    sigma: np.ndarray
    throughput: np.ndarray


MaterialFn = Callable[[np.ndarray, np.ndarray], dict]
NormalFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


class IndirectRenderer:
    """Path-traced interreflection on one Embree scene.

    tracer: the scene; normal_fn(points (N,3), triangles (N,)) -> (N, 3) unit normals (the exact
    geometry); material_fn(points, triangles) -> {'pd': (N,3), 'ps': (N,3), 'sigma': (N,)};
    brdf: a torchrefl.core.brdf model name; offset: origin offset along the normal (mm).
    """

    def __init__(
        self,
        tracer: RayTracer,
        normal_fn: NormalFn,
        material_fn: MaterialFn,
        brdf: str,
        *,
        offset: float = 0.01,
        min_bounces: int = 2,
        max_bounces: int = 32,
        seed: int = 0,
        chunk_paths: int = 1 << 17,
    ):
        brdf_mod.check_brdf_name(brdf, "synthetic.brdf")
        if min_bounces < 1 or max_bounces < min_bounces:
            raise GeometryError(
                f"IndirectRenderer min_bounces/max_bounces: need 1 <= min ({min_bounces}) <= max ({max_bounces})"
            )
        self.tracer = tracer
        self.normal_fn = normal_fn
        self.material_fn = material_fn
        self.brdf = brdf
        self.lobe = LOBES[brdf]
        self.offset = float(offset)
        self.min_bounces = int(min_bounces)
        self.max_bounces = int(max_bounces)
        self.seed = int(seed)
        self.chunk_paths = int(chunk_paths)

    # ------------------------------------------------------------------ sampling

    def _g(self, n, l, v, pd, ps, sigma) -> np.ndarray:
        with torch.no_grad():
            return brdf_mod.cosine_weighted_brdf(self.brdf, _t(n), _t(l), _t(v), _t(pd), _t(ps), _t(sigma)).numpy()

    def sample(self, n, v, pd, ps, sigma, u) -> tuple[np.ndarray, np.ndarray]:
        """Mixture sample: directions (N, 3) and their pdf (N,) from uniforms u (N, 3)."""
        return sample_mixture(self.lobe, n, v, pd, ps, sigma, u)

    # ------------------------------------------------------------------ paths

    def trace(
        self, points, normals, view, pd, ps, sigma, n_paths: int, rng: np.random.Generator, groups=None
    ) -> PathVertices:
        """Paths from origins (M of them: points, normals, view (M, 3), pd, ps (M, 3), sigma (M,)),
        n_paths each; returns their vertices y_k, k >= 1. groups (M,): origins averaged into one value
        (a texel's sub-samples), in contiguous runs; None = every origin on its own."""
        M = len(points)
        rep = lambda a: np.repeat(a, n_paths, axis=0)
        idx = np.repeat(np.arange(M), n_paths)
        x, n, wo = rep(points), rep(normals), rep(view)
        mpd, mps, msg = rep(pd), rep(ps), rep(sigma)
        T = np.ones((len(x), 3))
        u = grouped_points(n_paths, np.arange(M) if groups is None else np.asarray(groups), rng, 3)
        out = {k: [] for k in ("origin", "points", "normals", "wo", "pd", "ps", "sigma", "throughput")}
        for depth in range(self.max_bounces):
            if depth > 0:
                u = rng.random((len(x), 3))
            l, pdf = self.sample(n, wo, mpd, mps, msg, u)
            ok = (pdf > 0) & (row_dot(n, l) > 0)
            g = np.zeros((len(x), 3))
            if ok.any():
                i = np.flatnonzero(ok)
                g[i] = self._g(n[i], l[i], wo[i], mpd[i], mps[i], msg[i]) / pdf[i, None]
            T = T * g
            keep = np.flatnonzero(ok & (T.max(-1) > 0))
            x, n, l, T, idx = x[keep], n[keep], l[keep], T[keep], idx[keep]
            if not len(x):
                break
            origin = x + self.offset * n
            hits = self.tracer.closest_hit(origin, l)
            keep = np.flatnonzero(hits.hit)
            if not keep.size:
                break
            y = origin[keep] + hits.distance[keep, None] * l[keep]
            tri = hits.triangle[keep]
            ny = self.normal_fn(y, tri)
            wi = l[keep]
            flip = row_dot(ny, wi) > 0  # back side of a surface: shade the side the ray arrived at
            ny = np.where(flip[:, None], -ny, ny)
            mat = self.material_fn(y, tri)
            T, idx = T[keep], idx[keep]
            for k, a in (
                ("origin", idx),
                ("points", y),
                ("normals", ny),
                ("wo", -wi),
                ("pd", mat["pd"]),
                ("ps", mat["ps"]),
                ("sigma", mat["sigma"]),
                ("throughput", T),
            ):
                out[k].append(a)
            if depth + 1 >= self.min_bounces:  # Russian roulette before the next bounce
                q = np.minimum(0.95, T.max(-1))
                live = np.flatnonzero(rng.random(len(T)) < q)
                T = T[live] / q[live, None]
                y, ny, wi, idx, mat = y[live], ny[live], wi[live], idx[live], {k: v[live] for k, v in mat.items()}
            x, n, wo = y, ny, -wi
            mpd, mps, msg = mat["pd"], mat["ps"], mat["sigma"]
            if not len(x):
                break
        cat = lambda k, shape: np.concatenate(out[k]) if out[k] else np.zeros(shape)
        return PathVertices(
            cat("origin", (0,)).astype(np.int64),
            cat("points", (0, 3)),
            cat("normals", (0, 3)),
            cat("wo", (0, 3)),
            cat("pd", (0, 3)),
            cat("ps", (0, 3)),
            cat("sigma", (0,)),
            cat("throughput", (0, 3)),
        )

    def shade(self, verts: PathVertices, lights: np.ndarray, M: int) -> np.ndarray:
        """Next-event estimation: (P, M, 3) sum over each origin's path vertices of T g / C^2 * vis for
        lights (P, M, 3) (one position per light and origin: the rig's lights co-rotate)."""
        P = lights.shape[0]
        out = np.zeros((P, M, 3))
        if not len(verts.origin):
            return out
        y, ny = verts.points, verts.normals
        for p in range(P):
            pl = point_light(y, ny, lights[p][verts.origin], self.tracer, offset=self.offset)
            l, dist = pl.direction, pl.distance
            i = np.flatnonzero(pl.visible)
            if not i.size:
                continue
            g = self._g(ny[i], l[i], verts.wo[i], verts.pd[i], verts.ps[i], verts.sigma[i])
            value = verts.throughput[i] * g / (dist[i, None] ** 2)
            for c in range(3):
                out[p, :, c] = np.bincount(verts.origin[i], weights=value[:, c], minlength=M)
        return out

    def render(
        self, points, normals, view, pd, ps, sigma, lights, n_paths: int, progress=None, groups=None
    ) -> np.ndarray:
        """(P, M, 3) mean indirect g-term per origin and light: the sensor value is kappa * Y times it.

        points, normals, view: (M, 3); pd, ps: (M, 3); sigma: (M,); lights: (P, M, 3) world positions.
        groups (M,) int, optional: origins whose values are averaged afterwards (a texel's sub-samples),
        in contiguous runs: their first bounces are drawn from one stratified set (torchrefl.core.rqmc.grouped_points),
        so the group's mean is stratified over all its paths. Origins are processed in fixed chunks that
        never split a group (random numbers keyed by seed and chunk, so the result does not depend on which
        lights are rendered together or on the thread count).
        """
        M = len(points)
        lights = np.asarray(lights, dtype=np.float64)
        out = np.zeros((lights.shape[0], M, 3))
        if n_paths <= 0 or M == 0:
            return out
        per = max(1, self.chunk_paths // n_paths)
        if groups is None:
            starts = list(range(0, M, per))
        else:
            groups = np.asarray(groups)
            if groups.shape != (M,):
                raise GeometryError(f"groups has shape {groups.shape}, expected ({M},): one group per origin")
            first = np.r_[np.flatnonzero(np.r_[True, groups[1:] != groups[:-1]]), M]  # where each run starts
            starts = sorted(set(first[np.searchsorted(first, np.arange(0, M, per))].tolist()) - {M})
        ends = starts[1:] + [M]
        done = [0]

        def work(ci):
            a, b = starts[ci], ends[ci]
            rng = np.random.default_rng([self.seed, 0x61, ci])
            verts = self.trace(
                points[a:b],
                normals[a:b],
                view[a:b],
                pd[a:b],
                ps[a:b],
                sigma[a:b],
                n_paths,
                rng,
                None if groups is None else groups[a:b],
            )
            out[:, a:b] = self.shade(verts, lights[:, a:b], b - a) / n_paths
            done[0] += b - a
            if progress is not None:
                progress(done[0], M)

        # chunks run on the tracer's threads (Embree and most numpy release the GIL); each chunk's random
        # numbers are keyed by its index, so the result does not depend on the number of threads
        thread_map(work, range(len(starts)), self.tracer.threads)
        return out
