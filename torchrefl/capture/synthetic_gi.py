"""Interreflection for synthetic scenes: Monte Carlo path tracing with Embree (the renderer's truth).

The object sits in a dark room lit only by point lights; rays that escape carry nothing, and a
point light is never hit by a sampled ray, so the light reflected by a surface point x0 towards
the camera is direct light (computed elsewhere, analytically with a shadow ray) plus

    L_ind(x0, v) = sum over paths x0 -> y1 -> y2 -> ... of  T_k * g(y_k; l_k, wo_k) * Y / C_k^2 * vis_k,

one next-event (shadow-ray) term per path vertex y_k, where T_k is the product of g/pdf of the
sampled directions before y_k (and of the Russian-roulette divisions), g = f * cos the
cosine-weighted BRDF of torchrefl.brdf and C_k the distance from y_k to the light.

Sampling at every vertex is a one-sample mixture: with probability q = mean(Ps) / (mean(Pd) + mean(Ps))
the specular lobe (Torrance-Sparrow theta_h Gaussian or Ward), otherwise cosine-weighted; the
weight uses the mixture pdf (1 - q) cos/pi + q p_lobe, so the estimator is unbiased for any q.
The first bounce from each origin uses a scrambled Sobol set with a random toroidal shift per
origin (randomised QMC, unbiased); later bounces use independent uniforms. At least
`min_bounces` bounces are traced, then Russian roulette with survival min(0.95, max_c T).

Paths do not depend on the light (sampling uses only the BRDF), so one set of paths serves every
light: `trace` builds the vertices once, `shade` adds next-event estimation per light. All work is
vectorised over paths; the only Python loops run over bounce depth, lights and fixed-size chunks.
Deterministic in `seed` (random numbers are keyed by seed and chunk index, never by thread).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from scipy.stats import qmc

from torchrefl import brdf as brdf_mod
from torchrefl.errors import GeometryError
from torchrefl.rays import RayTracer

_LOBES = {"torrance_sparrow": "torrance_sparrow", "ward": "ward", "ward_normalised": "ward", "lambertian": None}


def _t(x) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float64))


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ni,ni->n", a, b)


def tangent_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangents t, b (N, 3) with t x b = n for unit normals n (N, 3) (Duff et al. 2017)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    c = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * c, -sign * n[:, 0]], -1)
    b = np.stack([c, sign + n[:, 1] ** 2 * a, -n[:, 1]], -1)
    return t, b


def _from_local(n, x, y, z):
    t, b = tangent_frame(n)
    return x[:, None] * t + y[:, None] * b + z[:, None] * n


def sample_cosine(n: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """(N, 3) cosine-weighted directions about unit normals n (N, 3); pdf = max(n.l, 0) / pi."""
    r = np.sqrt(u1)
    phi = 2 * np.pi * u2
    return _from_local(n, r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1.0 - u1, 0.0)))


def _ts_norm(sigma: np.ndarray) -> np.ndarray:
    """Z(sigma) = sigma^2 (1 - exp(-(pi/2)^2 / (2 sigma^2))), the normaliser of theta exp(-theta^2/(2 sigma^2))."""
    return sigma * sigma * -np.expm1(-(np.pi / 2) ** 2 / (2 * sigma * sigma))


def half_vector_pdf(model: str, cos_h: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Solid-angle pdf (N,) of half vectors at cos(theta_h) (upper hemisphere) for the lobe sampler.

    torrance_sparrow: theta_h on [0, pi/2] with density theta exp(-theta^2/(2 sigma^2)) / Z, phi uniform,
        so p_h = theta exp(-theta^2/(2 sigma^2)) / (2 pi Z sin theta) (theta / sin theta is bounded).
    ward: tan theta_h = sigma sqrt(-ln u) (Walter 2005), p_h = exp(-tan^2/sigma^2) / (pi sigma^2 cos^3).
    """
    c = np.clip(cos_h, 0.0, 1.0)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    theta = np.arctan2(s, c)
    if model == "torrance_sparrow":
        ratio = np.where(s > 1e-8, theta / np.maximum(s, 1e-300), 1.0)
        return ratio * np.exp(-theta * theta / (2 * sigma * sigma)) / (2 * np.pi * _ts_norm(sigma))
    if model == "ward":
        cc = np.maximum(c, 1e-12)
        tan2 = (s / cc) ** 2
        return np.where(c > 0, np.exp(-tan2 / (sigma * sigma)) / (np.pi * sigma * sigma * cc ** 3), 0.0)
    raise GeometryError(f"synthetic.brdf: no lobe sampler for '{model}'")


def sample_lobe(model: str, n: np.ndarray, v: np.ndarray, sigma: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """(N, 3) directions l: a half vector h drawn from the lobe about n, then l = reflect(v, h).

    n, v: (N, 3) unit; sigma: (N,) roughness (radians). Its pdf is `lobe_pdf` (over the whole sphere;
    directions below the surface simply carry zero BRDF).
    """
    sig = np.maximum(sigma, brdf_mod.SIGMA_EPS)
    if model == "torrance_sparrow":
        theta = sig * np.sqrt(-2.0 * np.log1p(-u1 * -np.expm1(-(np.pi / 2) ** 2 / (2 * sig * sig))))
        theta = np.minimum(theta, np.pi / 2)
    elif model == "ward":
        theta = np.arctan(sig * np.sqrt(-np.log(np.maximum(1.0 - u1, 1e-300))))
    else:
        raise GeometryError(f"synthetic.brdf: no lobe sampler for '{model}'")
    phi = 2 * np.pi * u2
    st = np.sin(theta)
    h = _from_local(n, st * np.cos(phi), st * np.sin(phi), np.cos(theta))
    return 2.0 * _dot(v, h)[:, None] * h - v


def lobe_pdf(model: str, n: np.ndarray, v: np.ndarray, l: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(N,) solid-angle pdf of `sample_lobe` producing direction l: p_h(h) / (4 |v.h|), h = +-(l+v)/|l+v|
    taken in the upper hemisphere of n."""
    sig = np.maximum(sigma, brdf_mod.SIGMA_EPS)
    h = l + v
    norm = np.linalg.norm(h, axis=-1)
    h = h / np.maximum(norm, 1e-300)[:, None]
    cos_h = _dot(n, h)
    h = np.where((cos_h < 0)[:, None], -h, h)
    cos_h = np.abs(cos_h)
    vh = np.abs(_dot(v, h))
    p = half_vector_pdf(model, cos_h, sig) / np.maximum(4.0 * vh, 1e-300)
    return np.where(norm > 1e-12, p, 0.0)


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
    brdf: a torchrefl.brdf model name; offset: origin offset along the normal (mm).
    """

    def __init__(self, tracer: RayTracer, normal_fn: NormalFn, material_fn: MaterialFn, brdf: str, *,
                 offset: float = 0.01, min_bounces: int = 2, max_bounces: int = 32, seed: int = 0,
                 chunk_paths: int = 1 << 17):
        brdf_mod.check_brdf_name(brdf, "synthetic.brdf")
        if min_bounces < 1 or max_bounces < min_bounces:
            raise GeometryError(f"synthetic.indirect_min_bounces/max_bounces: need 1 <= min ({min_bounces}) <= max ({max_bounces})")
        self.tracer = tracer
        self.normal_fn = normal_fn
        self.material_fn = material_fn
        self.brdf = brdf
        self.lobe = _LOBES[brdf]
        self.offset = float(offset)
        self.min_bounces = int(min_bounces)
        self.max_bounces = int(max_bounces)
        self.seed = int(seed)
        self.chunk_paths = int(chunk_paths)

    # ------------------------------------------------------------------ sampling

    def _g(self, n, l, v, pd, ps, sigma) -> np.ndarray:
        with torch.no_grad():
            return brdf_mod.cosine_weighted_brdf(self.brdf, _t(n), _t(l), _t(v), _t(pd), _t(ps), _t(sigma)).numpy()

    def _spec_prob(self, pd, ps) -> np.ndarray:
        if self.lobe is None:
            return np.zeros(len(pd))
        a, b = pd.mean(-1), ps.mean(-1)
        return np.where(a + b > 0, b / np.maximum(a + b, 1e-300), 0.0)

    def sample(self, n, v, pd, ps, sigma, u) -> tuple[np.ndarray, np.ndarray]:
        """Mixture sample: directions (N, 3) and their pdf (N,) from uniforms u (N, 3)."""
        q = self._spec_prob(pd, ps)
        spec = u[:, 2] < q
        l = sample_cosine(n, u[:, 0], u[:, 1])
        if spec.any():
            i = np.flatnonzero(spec)
            l[i] = sample_lobe(self.lobe, n[i], v[i], sigma[i], u[i, 0], u[i, 1])
        return l, self.mixture_pdf(n, v, l, pd, ps, sigma)

    def mixture_pdf(self, n, v, l, pd, ps, sigma) -> np.ndarray:
        q = self._spec_prob(pd, ps)
        p = (1.0 - q) * np.maximum(_dot(n, l), 0.0) / np.pi
        i = np.flatnonzero(q > 0)
        if i.size:
            p[i] += q[i] * lobe_pdf(self.lobe, n[i], v[i], l[i], sigma[i])
        return p

    # ------------------------------------------------------------------ paths

    def trace(self, points, normals, view, pd, ps, sigma, n_paths: int, rng: np.random.Generator) -> PathVertices:
        """Paths from origins (M of them: points, normals, view (M, 3), pd, ps (M, 3), sigma (M,)),
        n_paths each; returns their vertices y_k, k >= 1."""
        M = len(points)
        rep = lambda a: np.repeat(a, n_paths, axis=0)
        idx = np.repeat(np.arange(M), n_paths)
        x, n, wo = rep(points), rep(normals), rep(view)
        mpd, mps, msg = rep(pd), rep(ps), rep(sigma)
        T = np.ones((len(x), 3))
        # first bounce: randomised QMC (scrambled Sobol + a toroidal shift per origin)
        if n_paths > 1:   # the first n_paths points of a scrambled Sobol set: each uniform on [0,1)^3
            base = qmc.Sobol(3, scramble=True, seed=rng).random_base2(int(math.ceil(math.log2(n_paths))))[:n_paths]
        else:
            base = rng.random((n_paths, 3))
        u = np.mod(np.tile(base, (M, 1)) + rep(rng.random((M, 3))), 1.0)
        out = {k: [] for k in ("origin", "points", "normals", "wo", "pd", "ps", "sigma", "throughput")}
        for depth in range(self.max_bounces):
            if depth > 0:
                u = rng.random((len(x), 3))
            l, pdf = self.sample(n, wo, mpd, mps, msg, u)
            ok = (pdf > 0) & (_dot(n, l) > 0)
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
            flip = _dot(ny, wi) > 0           # back side of a surface: shade the side the ray arrived at
            ny = np.where(flip[:, None], -ny, ny)
            mat = self.material_fn(y, tri)
            T, idx = T[keep], idx[keep]
            for k, a in (("origin", idx), ("points", y), ("normals", ny), ("wo", -wi), ("pd", mat["pd"]),
                         ("ps", mat["ps"]), ("sigma", mat["sigma"]), ("throughput", T)):
                out[k].append(a)
            if depth + 1 >= self.min_bounces:      # Russian roulette before the next bounce
                q = np.minimum(0.95, T.max(-1))
                live = np.flatnonzero(rng.random(len(T)) < q)
                T = T[live] / q[live, None]
                y, ny, wi, idx, mat = y[live], ny[live], wi[live], idx[live], {k: v[live] for k, v in mat.items()}
            x, n, wo = y, ny, -wi
            mpd, mps, msg = mat["pd"], mat["ps"], mat["sigma"]
            if not len(x):
                break
        cat = lambda k, shape: np.concatenate(out[k]) if out[k] else np.zeros(shape)
        return PathVertices(cat("origin", (0,)).astype(np.int64), cat("points", (0, 3)), cat("normals", (0, 3)),
                            cat("wo", (0, 3)), cat("pd", (0, 3)), cat("ps", (0, 3)), cat("sigma", (0,)),
                            cat("throughput", (0, 3)))

    def shade(self, verts: PathVertices, lights: np.ndarray, M: int) -> np.ndarray:
        """Next-event estimation: (P, M, 3) sum over each origin's path vertices of T g / C^2 * vis for
        lights (P, M, 3) (one position per light and origin: the rig's lights co-rotate)."""
        P = lights.shape[0]
        out = np.zeros((P, M, 3))
        if not len(verts.origin):
            return out
        y, ny = verts.points, verts.normals
        for p in range(P):
            lp = lights[p][verts.origin]
            to = lp - y
            dist = np.sqrt(_dot(to, to))
            l = to / np.maximum(dist, 1e-12)[:, None]
            i = np.flatnonzero(_dot(ny, l) > 0)
            if not i.size:
                continue
            i = i[self.tracer.visible(y[i], ny[i], lp[i], offset=self.offset)]
            if not i.size:
                continue
            g = self._g(ny[i], l[i], verts.wo[i], verts.pd[i], verts.ps[i], verts.sigma[i])
            value = verts.throughput[i] * g / (dist[i, None] ** 2)
            for c in range(3):
                out[p, :, c] = np.bincount(verts.origin[i], weights=value[:, c], minlength=M)
        return out

    def render(self, points, normals, view, pd, ps, sigma, lights, n_paths: int, progress=None) -> np.ndarray:
        """(P, M, 3) mean indirect g-term per origin and light: the sensor value is kappa * Y times it.

        points, normals, view: (M, 3); pd, ps: (M, 3); sigma: (M,); lights: (P, M, 3) world positions.
        Origins are processed in fixed chunks (random numbers keyed by seed and chunk, so the result does
        not depend on which lights are rendered together).
        """
        M = len(points)
        lights = np.asarray(lights, dtype=np.float64)
        out = np.zeros((lights.shape[0], M, 3))
        if n_paths <= 0 or M == 0:
            return out
        per = max(1, self.chunk_paths // n_paths)
        starts = list(range(0, M, per))
        done = [0]

        def work(ci):
            a = starts[ci]
            b = min(a + per, M)
            rng = np.random.default_rng([self.seed, 0x61, ci])
            verts = self.trace(points[a:b], normals[a:b], view[a:b], pd[a:b], ps[a:b], sigma[a:b], n_paths, rng)
            out[:, a:b] = self.shade(verts, lights[:, a:b], b - a) / n_paths
            done[0] += b - a
            if progress is not None:
                progress(done[0], M)

        # chunks run on the tracer's threads (Embree and most numpy release the GIL); each chunk's random
        # numbers are keyed by its index, so the result does not depend on the number of threads
        if self.tracer.threads > 1 and len(starts) > 1:
            with ThreadPoolExecutor(self.tracer.threads) as pool:
                list(pool.map(work, range(len(starts))))
        else:
            for ci in range(len(starts)):
                work(ci)
        return out
