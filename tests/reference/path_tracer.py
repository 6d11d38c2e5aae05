"""A small reference path tracer for point lights on a triangle mesh, written from the equations.

It shares no code with torchrefl: it imports only numpy and embreex (the Embree binding) and has its own
BRDF, its own point-light term with shadow rays, its own direction samplers and its own Monte Carlo
estimator. It exists so that the transport levels (torchrefl.transport.levels) can be checked against a
renderer that cannot share their mistakes (tests/transport/levels/test_levels_vs_reference.py). It is
slow-but-obvious: plain numpy over all paths at once, no caches, no density estimation, no smoothing.

Physics (docs/model.md): Torrance-Sparrow, eq. 2.9,

    f(l, v) = Pd / pi + Ps exp(-theta_h^2 / (2 sigma^2)) / (pi cos_l cos_v),   theta_h = atan2(|n x h|, n.h),

used as the cosine-weighted BRDF g = f max(cos_l, 0), in which cos_l cancels from the lobe; cos_v is held
above 1e-4 where it divides (the model's one clamp). A point light of radiant intensity Y at distance d
gives the irradiance Y cos_l / d^2 when the segment to it is free (an Embree shadow ray), and the camera
reads i = kappa L_o (kappa per channel).

Modes (what the camera reads at an observed point x0 with outgoing direction v0):

- 'direct': kappa Y vis g0(l, v0) / d^2, the full BRDF, no interreflection: what the local level models.
- 'diffuse': 'direct' plus interreflected light carried by all-diffuse paths only: the observed point
  responds to indirect light with Pd0 / pi, and every interreflection vertex reflects (the light and the
  light from other vertices) with Pd / pi only. That is the radiosity level's model, local +
  kappa Pd / pi H with H the irradiance of the diffuse radiosity solution B = rho (E + F B).
- 'full': 'direct' plus all interreflection with the full BRDF at the observed point and at every vertex:
  what the photon level models.

Estimator: per observed point, `samples` independent camera paths. The first direction leaves x0, each
later one leaves the vertex it hit; 'diffuse' samples cosine-weighted directions (weight Pd), 'full' a
one-sample mixture of a cosine-weighted direction and the lobe sampler below (probability 1/2 each where
Ps > 0) with the weight g / (mixture pdf). At every interreflection vertex the point light is sampled
explicitly (next-event estimation with a shadow ray); a point light cannot be hit by a sampled ray, so
nothing is counted twice. Paths end on a miss, on a hit on the back of a face (the mesh is a one-sided
scanned sheet: light behind it is not modelled), by Russian roulette from the third scattering on
(survival min(0.95, max weight of the scattering), unbiased), and after MAX_DEPTH scatterings (the only
bias: the light after 24 interreflections. Measured on the test's glossy fold with the same random numbers,
scatterings 5-6 add 7e-4 of the interreflected light and 7-24 add 5e-6: each two bounces keep about 1/40).
The standard error per (light, point, channel) is the sample standard deviation of the independent paths'
values over sqrt(samples).

Lobe sampler (derived here): the half vector's polar angle from n is Rayleigh distributed,
theta = sigma sqrt(-2 ln(1 - u1)), phi = 2 pi u2, i.e. the density over the half vector's solid angle
p_h = theta exp(-theta^2 / (2 sigma^2)) / (2 pi sigma^2 sin theta); the direction is the reflection of v
about h, l = 2 (v.h) h - v, with density p_h / (4 v.h). Half vectors beyond 90 degrees, or reflections
below the surface, are dropped (value 0), which keeps the estimator unbiased.

Surface: a triangle mesh with per-vertex materials. A hit takes the oriented geometric normal of its face
(the front is the side its corners' vertex normals point to; hit_normals='vertex': the nearest corner's
vertex normal where it faces the ray, a variant for checking that choice) and the material of the face's
nearest corner (largest barycentric weight). Observed points come with their own position, normal, view
direction and material. Rays start `offset` along the normal (Embree's tnear is 0), shadow rays end
`offset` short of the light.
"""

from __future__ import annotations

import numpy as np
from embreex import mesh_construction, rtcore_scene

MODES = ("direct", "diffuse", "full")
MAX_DEPTH = 24
COS_V_MIN = 1e-4
_FAR = 1e30


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ni,ni->n", a, b)


def _frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents t, b with (t, b, n) orthonormal, for unit normals n (N, 3)."""
    helper = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = _unit(np.cross(helper, n))
    return t, np.cross(n, t)


def _around(n: np.ndarray, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit vectors at polar angle theta and azimuth phi about n."""
    t, b = _frame(n)
    s = np.sin(theta)
    return (s * np.cos(phi))[:, None] * t + (s * np.sin(phi))[:, None] * b + np.cos(theta)[:, None] * n


def half_angle(n: np.ndarray, l: np.ndarray, v: np.ndarray) -> np.ndarray:
    """theta_h, the angle between n and the half vector of l and v, as atan2(|n x h|, n.h)."""
    h = l + v
    return np.arctan2(np.linalg.norm(np.cross(n, h), axis=-1), _dot(n, h))


def cosine_weighted_brdf(n, l, v, pd, ps, sigma, diffuse_only: bool = False) -> np.ndarray:
    """(N, 3) g = f(l, v) max(n.l, 0) of eq. 2.9 (zero where n.l <= 0 or n.v <= 0); diffuse_only: Pd / pi n.l."""
    cos_l, cos_v = _dot(n, l), _dot(n, v)
    front = (cos_l > 0) & (cos_v > 0)
    g = pd * (np.maximum(cos_l, 0.0) / np.pi)[:, None]
    if not diffuse_only:
        th = half_angle(n, l, v)
        lobe = np.exp(-(th**2) / (2.0 * sigma**2)) / (np.pi * np.maximum(cos_v, COS_V_MIN))
        g = g + ps * lobe[:, None]
    return np.where(front[:, None], g, 0.0)


def lobe_pdf(n, l, v, sigma) -> np.ndarray:
    """(N,) solid-angle density of the lobe sampler's direction l (module doc)."""
    h = _unit(l + v)
    th = half_angle(n, l, v)
    s = np.sin(th)
    ratio = np.where(s > 1e-8, th / np.maximum(s, 1e-300), 1.0)
    p_h = ratio * np.exp(-(th**2) / (2.0 * sigma**2)) / (2.0 * np.pi * sigma**2)
    vh = _dot(v, h)
    ok = (th < np.pi / 2) & (vh > 0)
    return np.where(ok, p_h / (4.0 * np.maximum(vh, 1e-300)), 0.0)


def sample_cosine(n, rng) -> np.ndarray:
    u1, u2 = rng.random(len(n)), rng.random(len(n))
    return _around(n, np.arcsin(np.sqrt(u1)), 2.0 * np.pi * u2)


def sample_lobe(n, v, sigma, rng) -> np.ndarray:
    """Directions by the lobe sampler (module doc); rows whose half vector or reflection is invalid are NaN."""
    u1, u2 = rng.random(len(n)), rng.random(len(n))
    theta = sigma * np.sqrt(-2.0 * np.log1p(-u1))
    h = _around(n, np.minimum(theta, np.pi / 2), 2.0 * np.pi * u2)
    l = 2.0 * _dot(v, h)[:, None] * h - v
    bad = (theta >= np.pi / 2) | (_dot(v, h) <= 0) | (_dot(n, l) <= 0)
    return np.where(bad[:, None], np.nan, l)


def scatter(n, v, pd, ps, sigma, diffuse_only, rng):
    """Next directions (N, 3) and weights g / pdf (N, 3) leaving points with normals n towards v (module doc);
    diffuse_only: cosine-weighted directions with the weight Pd. Rows with a zero weight end their path."""
    N = len(n)
    if diffuse_only:
        return sample_cosine(n, rng), pd.copy()
    glossy = ps.max(1) > 0
    q = np.where(glossy, 0.5, 0.0)
    use_lobe = rng.random(N) < q
    d = sample_cosine(n, rng)
    if use_lobe.any():
        d[use_lobe] = sample_lobe(n[use_lobe], v[use_lobe], sigma[use_lobe], rng)
    ok = np.isfinite(d).all(1)
    d = np.where(ok[:, None], d, n)  # a placeholder direction for dropped samples (weight 0)
    cos = np.maximum(_dot(n, d), 0.0)
    pdf = (1.0 - q) * cos / np.pi + q * lobe_pdf(n, d, v, sigma)
    g = cosine_weighted_brdf(n, d, v, pd, ps, sigma)
    w = np.where((ok & (pdf > 0))[:, None], g / np.maximum(pdf, 1e-300)[:, None], 0.0)
    return d, w


class ReferenceRenderer:
    """Point-light images of observed points on a triangle mesh (module doc).

    vertices (V, 3), faces (F, 3): the mesh; vertex_normals (V, 3): orient each face's front (only their
    sum over a face's corners is used); pd (V, 3), ps (V, 3), sigma (V,): the material of each vertex;
    offset: ray origin offset (scene units); seed: the random numbers; hit_normals: 'face' or 'vertex'
    (the normal at a hit, module doc).
    """

    def __init__(
        self, vertices, faces, vertex_normals, pd, ps, sigma, *, offset: float, seed: int = 0, hit_normals="face"
    ):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        a, b, c = (self.vertices[self.faces[:, k]] for k in range(3))
        fn = _unit(np.cross(b - a, c - a))
        side = np.einsum("fi,fi->f", fn, np.asarray(vertex_normals, dtype=np.float64)[self.faces].sum(1))
        self.face_normals = np.where((side < 0)[:, None], -fn, fn)
        vn = np.asarray(vertex_normals, dtype=np.float64)
        self.vertex_normals = vn / np.maximum(np.linalg.norm(vn, axis=-1, keepdims=True), 1e-300)
        self.hit_normals = hit_normals
        self.pd, self.ps = np.asarray(pd, dtype=np.float64), np.asarray(ps, dtype=np.float64)
        self.sigma = np.asarray(sigma, dtype=np.float64)
        self.offset = float(offset)
        self.seed = seed
        self.scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(
            self.scene, np.ascontiguousarray(self.vertices, np.float32), np.ascontiguousarray(self.faces, np.int32)
        )

    # ------------------------------------------------------------------ rays

    def _start(self, x, n, d):
        """Ray origins offset along n towards the side d leaves on."""
        side = np.where(_dot(n, d) >= 0, self.offset, -self.offset)
        return x + side[:, None] * n

    def _intersect(self, origins, dirs):
        """(face (N,) -1 on a miss, barycentric u, v (N,), distance (N,))."""
        n = len(origins)
        if n == 0:
            e = np.zeros(0)
            return np.zeros(0, np.int64), e, e, e
        res = self.scene.run(
            np.ascontiguousarray(origins, np.float32),
            np.ascontiguousarray(dirs, np.float32),
            dists=np.full(n, _FAR, np.float32),
            query="INTERSECT",
            output=1,
        )
        return res["primID"].astype(np.int64), res["u"].astype(np.float64), res["v"].astype(np.float64), res["tfar"]

    def _free(self, x, n, target) -> np.ndarray:
        """(N,) bool: the segment from x (offset along n) to target is not blocked."""
        d = target - x
        o = self._start(x, n, d)
        seg = target - o
        dist = np.linalg.norm(seg, axis=-1)
        far = np.maximum(dist - self.offset, 0.0)
        out = np.ones(len(x), dtype=bool)
        idx = np.flatnonzero(far > 0)
        if idx.size:
            hit = self.scene.run(
                np.ascontiguousarray(o[idx], np.float32),
                np.ascontiguousarray(seg[idx] / dist[idx, None], np.float32),
                dists=far[idx].astype(np.float32),
                query="OCCLUDED",
            )
            out[idx] = hit != 0  # embreex: 0 = occluded, -1 = free
        return out

    # ------------------------------------------------------------------ light

    def _light(self, x, n, v, pd, ps, sigma, light, diffuse_only):
        """(N, 3) Y-free reflected radiance of a point light at `light` (N, 3): vis g(l, v) / d^2."""
        to = light - x
        d2 = _dot(to, to)
        l = to / np.sqrt(d2)[:, None]
        g = cosine_weighted_brdf(n, l, v, pd, ps, sigma, diffuse_only)
        lit = (_dot(n, l) > 0) & (_dot(n, v) > 0)
        vis = np.zeros(len(x), dtype=bool)
        idx = np.flatnonzero(lit)
        if idx.size:
            vis[idx] = self._free(x[idx], n[idx], light[idx])
        return g * (vis / d2)[:, None]

    # ------------------------------------------------------------------ images

    def render(self, points, normals, views, pd, ps, sigma, lights, intensity, kappa, mode: str, samples: int = 64):
        """Camera values and their standard errors, both (P, N, 3), of N observed points under P point lights.

        points, normals, views (N, 3): position, unit normal, unit direction towards the camera; pd (N, 3),
        ps (N, 3), sigma (N,): the observed points' material; lights (P, N, 3): the light position as each
        point's image saw it (a co-rotating rig moves the light with the scan); intensity (P, 3): Y;
        kappa (3,); mode: 'direct', 'diffuse' or 'full' (module doc); samples: paths per point.
        """
        if mode not in MODES:
            raise ValueError(f"mode {mode!r}, expected one of {MODES}")
        x0, n0, v0 = (np.asarray(a, dtype=np.float64) for a in (points, normals, views))
        pd0, ps0, sg0 = (np.asarray(a, dtype=np.float64) for a in (pd, ps, sigma))
        lights = np.asarray(lights, dtype=np.float64)
        scale = np.asarray(kappa, dtype=np.float64)[None, None] * np.asarray(intensity, dtype=np.float64)[:, None]
        P, N = lights.shape[:2]
        direct = np.stack([self._light(x0, n0, v0, pd0, ps0, sg0, lights[p], False) for p in range(P)])
        if mode == "direct":
            return scale * direct, np.zeros_like(direct)
        diffuse_only = mode == "diffuse"
        rng = np.random.default_rng(self.seed)
        S = int(samples)
        origin = np.repeat(np.arange(N), S)  # path i belongs to observed point origin[i]
        value = np.zeros((P, N * S, 3))
        path = np.arange(N * S)
        x, n, v = x0[origin], n0[origin], v0[origin]
        m_pd, m_ps, m_sg = pd0[origin], ps0[origin], sg0[origin]
        beta = np.ones((N * S, 3))
        for depth in range(1, MAX_DEPTH + 1):
            d, w = scatter(n, v, m_pd, m_ps, m_sg, diffuse_only, rng)
            beta = beta * w
            if depth >= 3:  # Russian roulette from the third scattering on
                survive = np.minimum(0.95, w.max(1))
                keep = rng.random(len(w)) < survive
                beta = np.where(keep[:, None], beta / np.maximum(survive, 1e-300)[:, None], 0.0)
            alive = beta.max(1) > 0
            face, bu, bv, _ = self._intersect(self._start(x, n, d), d)
            alive &= face >= 0
            fn = self.face_normals[np.maximum(face, 0)]
            alive &= _dot(fn, d) < 0  # the front of the face: the back of the scanned sheet absorbs
            idx = np.flatnonzero(alive)
            if idx.size == 0:
                break
            f = face[idx]
            u, vv = bu[idx], bv[idx]
            corner = np.where(u >= vv, np.where(u > 1 - u - vv, 1, 0), np.where(vv > 1 - u - vv, 2, 0))
            vert = self.faces[f, corner]
            tri = self.vertices[self.faces[f]]
            x = (1 - u - vv)[:, None] * tri[:, 0] + u[:, None] * tri[:, 1] + vv[:, None] * tri[:, 2]
            n = fn[idx]
            if self.hit_normals == "vertex":  # the nearest corner's normal where it faces the ray
                vn = self.vertex_normals[vert]
                n = np.where((_dot(vn, d[idx]) < 0)[:, None], vn, n)
            v = -d[idx]
            m_pd, m_ps, m_sg = self.pd[vert], self.ps[vert], self.sigma[vert]
            beta, path = beta[idx], path[idx]
            for p in range(P):
                e = self._light(x, n, v, m_pd, m_ps, m_sg, lights[p, origin[path]], diffuse_only)
                value[p, path] += beta * e
        value = value.reshape(P, N, S, 3)
        mean = value.mean(2)
        stderr = value.std(2, ddof=1) / np.sqrt(S)
        return scale * (direct + mean), scale * stderr
