"""Photon tracing with Embree (Method III, dissertation Ch.5): light paths from point lights over the texel mesh.

Photons are aimed at the object: a photon of source s (position L, radiant intensity Y, RGB) first
lands on texel t with probability proportional to the texel's unshadowed direct flux geometry (drawn by
systematic sampling)
    a_t = A_t max(n_t.l, 0) vis_t / |L - x_t|^2          (vis by an Embree shadow ray),
which is exactly the density of a ray from L whose first hit is t, so every photon carries the same
    Phi = Y * sum_t a_t / N                              (N photons of that source),
and no photon is wasted on directions that miss. The first hit is not stored (direct light is
computed analytically by the local terms) and needs no ray: the photon starts at the texel with
wi = l. Later hits are found with Embree; a hit's texel is the nearest mesh vertex (mesh vertices
are texel grid points). From the first hit on, the photon is scattered by the current BRDF of the texel it hit: a direction wo from the mixture of the
cosine-weighted and specular-lobe samplers (torchrefl.transport.lobe_sampling) with weight
    w = f(wi -> wo) cos(n, wo) / pdf(wo) = g(n, l=wi, v=wo) cos(n, wo) / (cos(n, wi) pdf(wo))
(g = f cos_l, torchrefl.brdf.cosine_weighted_brdf; non-reciprocal lobes are evaluated with the light
on the incident side, the way the fitter and the renderer use them), then Russian roulette with
survival q = min(0.95, max_c w) and Phi <- Phi w / q. Every later hit on the front side of the mesh
(face normal, oriented like the texel normals, towards wi) is stored with the texel, the incident direction wi (towards where the photon came from)
and Phi; hits on the back of the scanned surface absorb the photon (the unscanned side is not modelled).
Photons are scattered about the texel normal, or the face normal where the texel normal faces away
from the photon (grazing arrival on a curved or folded mesh).

Deterministic in `seed`: random numbers are keyed by (seed, refresh, source, chunk), never by thread.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch

from torchrefl import brdf as brdf_mod
from torchrefl.errors import GeometryError
from torchrefl.rays import RayTracer
from torchrefl.transport.lobe_sampling import LOBES, row_dot, sample_mixture, specular_probability, tangent_frame

CHUNK = 1 << 17          # photons per work unit
COLLECT_COS = 0.9        # a face corner collects photons for its texel when their normals agree this well


@dataclass
class PhotonHits:
    """Stored photon hits (second and later bounces) of all sources.

    source: (N,) int64 index of the emitting source; texel: (N,) int64 receiving texel;
    direction: (N, 3) unit incident direction wi; power: (N, 3) flux Phi;
    emitter: (N,) int64 texel of the photon's last scattering; diffuse_per_pd: (N, 3) the share of Phi
    that is linear in the emitter's Pd, per unit Pd: Phi (cos_i / pi) / g at that scattering, so that
    Phi(Pd') = Phi + diffuse_per_pd (Pd' - Pd) exactly for the last bounce.
    emitted: (S,) photons emitted per source; rays: closest-hit rays traced in all.
    """

    source: np.ndarray
    texel: np.ndarray
    direction: np.ndarray
    power: np.ndarray
    emitted: np.ndarray
    rays: int
    emitter: np.ndarray | None = None
    diffuse_per_pd: np.ndarray | None = None

    @property
    def count(self) -> int:
        return int(len(self.texel))


@dataclass
class TexelMaterial:
    """Current reflectance of every texel, for scattering: pd (T, 3), ps (T, 3), sigma (T,) float64."""

    pd: np.ndarray
    ps: np.ndarray
    sigma: np.ndarray
    q: np.ndarray | None = None          # specular sampling probability per texel (set by PhotonTracer.trace)

    @classmethod
    def from_tensors(cls, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor) -> "TexelMaterial":
        T = pd.shape[0]
        as64 = lambda x: x.detach().cpu().double().numpy()
        return cls(as64(pd), np.ascontiguousarray(np.broadcast_to(as64(ps), (T, 3))), as64(sigma))


class PhotonTracer:
    """Photon tracing over the texel mesh of a Surface.

    Photon densities use each texel's collection area, one third of the area of the mesh faces around
    its vertex (the part of the mesh whose hits snap to it: barycentric regions are a third each),
    counting only faces whose normal agrees with the texel's (cos > COLLECT_COS): a face cutting across
    a fold still scatters photons but does not count towards the fold texels' densities.

    tracer: Embree scene of surface.mesh_vertices / mesh_faces; texel_index, positions, normals:
    the Surface's (mesh vertex v is grid point v; texel_index maps texels to grid points); brdf: model name;
    offset: origin offset along the normal for scattered rays (scene units); max_bounces: cap on the
    bounces after the first hit; min_bounces: bounces before Russian roulette starts.
    """

    def __init__(self, tracer: RayTracer, texel_index: np.ndarray, positions: np.ndarray, normals: np.ndarray,
                 brdf: str, *,
                 offset: float = 0.01, min_bounces: int = 1, max_bounces: int = 16):
        brdf_mod.check_brdf_name(brdf, "reflectance.brdf")
        if min_bounces < 0 or max_bounces < max(1, min_bounces):
            raise GeometryError(f"photon.min_bounces/max_bounces: need 0 <= min ({min_bounces}) <= max ({max_bounces}), max >= 1")
        self.tracer = tracer
        self.brdf = brdf
        self.lobe = LOBES[brdf]
        self.positions = np.ascontiguousarray(positions, dtype=np.float64)
        self.normals = np.ascontiguousarray(normals, dtype=np.float64)
        self._landing: dict = {}
        self.offset = float(offset)
        self.min_bounces = int(min_bounces)
        self.max_bounces = int(max_bounces)
        V = len(tracer.vertices)
        texel_index = np.asarray(texel_index, dtype=np.int64)
        if texel_index.size and texel_index.max() >= V:
            raise GeometryError(f"photon tracing: texel grid index {int(texel_index.max())} is not a mesh vertex "
                                f"(the mesh has {V}); the mesh must be the texel grid's triangulation")
        self.vertex_texel = np.full(V, -1, dtype=np.int64)
        self.vertex_texel[texel_index] = np.arange(len(texel_index))
        faces = np.asarray(tracer.faces, dtype=np.int64)
        if faces.size and (self.vertex_texel[faces] < 0).any():
            raise GeometryError("photon tracing: some mesh faces use grid points that are not texels")
        self.faces = faces
        self.frame_t, self.frame_b = tangent_frame(self.normals)
        verts = np.asarray(tracer.vertices, dtype=np.float64)
        fa = 0.5 * np.linalg.norm(np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]), axis=1)
        fn = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]) if faces.size else np.zeros((0, 3))
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        side = np.sign(row_dot(fn, self.normals[self.vertex_texel[faces]].sum(1))) if faces.size else np.zeros(0)
        self.face_normals = fn * np.where(side == 0, 1.0, side)[:, None]
        # a corner of a face collects for its texel only where the face lies along the texel's surface
        # (normals within ~25 deg): faces that cut across a fold or a crease (their normal between the two
        # sides) still scatter photons but do not count in the fold texels' density, which would
        # otherwise average the crease strip's (higher) irradiance into the plates'
        corner_texel = self.vertex_texel[faces] if faces.size else np.zeros((0, 3), dtype=np.int64)
        self.collects = (np.einsum("fi,fci->fc", self.face_normals, self.normals[corner_texel]) > COLLECT_COS
                         if faces.size else np.zeros((0, 3), dtype=bool))
        self.areas = np.bincount(corner_texel.ravel(), weights=(np.repeat(fa[:, None] / 3.0, 3, 1) * self.collects).ravel(),
                                 minlength=len(texel_index)) if faces.size else np.zeros(len(texel_index))

    def landing(self, source: np.ndarray) -> np.ndarray:
        """(T,) a_t of the module docstring for one source position (cached per position)."""
        key = tuple(np.round(np.asarray(source, dtype=np.float64), 9))
        if key not in self._landing:
            to = np.asarray(source, dtype=np.float64)[None] - self.positions
            d2 = row_dot(to, to)
            cos = row_dot(self.normals, to) / np.sqrt(np.maximum(d2, 1e-300))
            a = np.where(cos > 0, self.areas * cos / np.maximum(d2, 1e-300), 0.0)
            lit = np.flatnonzero(a > 0)
            if lit.size:
                vis = self.tracer.visible(self.positions[lit], self.normals[lit], to[lit] + self.positions[lit],
                                          offset=self.offset)
                a[lit[~vis]] = 0.0
            self._landing[key] = a
        return self._landing[key]

    # ------------------------------------------------------------------ pieces

    def hit_texels(self, triangle: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Texel of each hit (the face vertex with the largest barycentric weight) and whether the hit
        counts in that texel's density (self.collects)."""
        w = np.stack([1.0 - bary[:, 0] - bary[:, 1], bary[:, 0], bary[:, 1]], -1)
        corner = np.argmax(w, axis=1)
        return self.vertex_texel[self.faces[triangle, corner]], self.collects[triangle, corner]

    def shading_normals(self, texel: np.ndarray, triangle: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The texel's normal, or the hit face's where the texel normal faces away from wi (a photon arriving
        at a grazing angle on a curved or folded mesh: the smooth normal would absorb it); and (N,) bool
        True where it is the texel's own."""
        n = self.normals[texel]
        own = row_dot(n, wi) > 1e-6
        if not own.all():
            n[~own] = self.face_normals[triangle[~own]]
        return n, own

    def scatter(self, n, wi, texel, mat: TexelMaterial, u, own_normal=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Outgoing directions (N, 3), weights (N, 3) f cos_o / pdf for photons arriving along -wi, and the
        part of the weight per unit Pd (N,) (cos_i / pi) cos_o / (cos_i pdf) = cos_o / (pi pdf).
        own_normal (N,) bool: n is the texel's normal (its precomputed tangent frame is used)."""
        pd, ps, sg = mat.pd[texel], mat.ps[texel], mat.sigma[texel]
        if own_normal is None or own_normal.all():
            frame = (self.frame_t[texel], self.frame_b[texel])
        else:
            frame = tangent_frame(n)
        q = None if mat.q is None else mat.q[texel]
        wo, pdf, cos_h = sample_mixture(self.lobe, n, wi, pd, ps, sg, u, frame=frame, q=q, with_cos_h=True)
        cos_o = row_dot(n, wo)
        cos_i = row_dot(n, wi)
        ok = (pdf > 0) & (cos_o > 0)
        w = np.zeros((len(n), 3))
        w_pd = np.zeros(len(n))
        if ok.any():
            i = np.flatnonzero(ok)
            # g(n, l=wi, v=wo) = Pd cos_i / pi + Ps D(theta_h) G(cos_i, cos_o): the decomposition of torchrefl.brdf
            # that the local terms use, evaluated from the sampler's half vector
            g = pd[i] * (np.maximum(cos_i[i], 0.0) / np.pi)[:, None]
            if self.lobe is not None:
                c = np.clip(cos_h[i], -1.0, 1.0)
                t = lambda x: torch.from_numpy(np.ascontiguousarray(x))
                theta_h = np.arctan2(np.sqrt(np.maximum(1.0 - c * c, 0.0)), c)
                with torch.no_grad():
                    spec = (brdf_mod.specular_lobe(self.brdf, t(theta_h), t(sg[i]))
                            * brdf_mod.specular_geometry(self.brdf, t(cos_i[i]), t(cos_o[i]))).numpy()
                g += ps[i] * spec[:, None]
            scale = cos_o[i] / (cos_i[i] * pdf[i])
            w[i] = g * scale[:, None]
            w_pd[i] = np.where(cos_i[i] > 0, cos_i[i] / np.pi, 0.0) * scale
        return wo, w, w_pd

    # ------------------------------------------------------------------ paths

    def trace_chunk(self, source: np.ndarray, intensity: np.ndarray, n: int, n_total: int, mat: TexelMaterial,
                    rng: np.random.Generator) -> tuple[list, int]:
        """n photons of one source (out of n_total for that source); returns ([texel, wi, power] arrays, rays)."""
        a = self.landing(source)
        total = float(a.sum())
        out_t, out_d, out_p, out_e, out_k = [], [], [], [], []
        if total <= 0:
            return [out_t, out_d, out_p, out_e, out_k], 0
        # systematic sampling: n stratified positions on the cdf (lower variance than independent draws, O(T + n),
        # and the photons come out ordered by texel, which keeps the rays coherent)
        edges = np.floor(np.concatenate([[0.0], np.cumsum(a / total)]) * n + rng.random())
        counts = np.diff(edges).astype(np.int64)
        texel = np.repeat(np.arange(len(a)), counts)
        n = len(texel)
        y = self.positions[texel]
        wi = np.asarray(source, dtype=np.float64)[None] - y
        wi /= np.linalg.norm(wi, axis=1, keepdims=True)
        power = np.broadcast_to(intensity * (total / n_total), (n, 3)).copy()
        n_t = self.normals[texel]
        own = None
        emitter = per_pd = origin = d = None          # origin, d: the rays of the previous bounce
        rays = 0
        for depth in range(self.max_bounces + 1):
            if depth > 0:
                # the work units of `trace` run on tracer.threads threads; inside a unit, rays go through Embree
                # on that unit's thread (a second pool per bounce would oversubscribe the cores)
                hits = self.tracer.closest_hit(origin, d, threads=1)
                rays += len(origin)
                keep = np.flatnonzero(hits.hit)
                if not keep.size:
                    break
                y = origin[keep] + hits.distance[keep, None] * d[keep]
                texel, collect = self.hit_texels(hits.triangle[keep], hits.barycentric[keep])
                wi = -d[keep]
                power, emitter, per_pd = power[keep], emitter[keep], per_pd[keep]
                n_t, own = self.shading_normals(texel, hits.triangle[keep], wi)
                front = row_dot(self.face_normals[hits.triangle[keep]], wi) > 0
                if not front.all():
                    y, texel, wi, power, n_t, own = y[front], texel[front], wi[front], power[front], n_t[front], own[front]
                    emitter, per_pd, collect = emitter[front], per_pd[front], collect[front]
            if depth > 0 and len(texel):
                c = slice(None) if collect.all() else collect
                out_t.append(texel[c])
                out_d.append(wi[c])
                out_p.append(power[c])
                out_e.append(emitter[c])
                out_k.append(per_pd[c])
            if depth == self.max_bounces or not len(texel):
                break
            wo, w, w_pd = self.scatter(n_t, wi, texel, mat, rng.random((len(texel), 3)), own_normal=own)
            per_pd = power * w_pd[:, None]
            power = power * w
            if depth + 1 > self.min_bounces:
                q = np.minimum(0.95, w.max(-1))
                live = rng.random(len(q)) < q
                power = power[live] / q[live, None]
                per_pd = per_pd[live] / q[live, None]
            else:
                live = w.max(-1) > 0
                power, per_pd = power[live], per_pd[live]
            emitter = texel[live]
            origin = y[live] + self.offset * n_t[live]
            d = wo[live]
            if not len(d):
                break
        return [out_t, out_d, out_p, out_e, out_k], rays

    def trace(self, sources: np.ndarray, intensities: np.ndarray, photons_per_source: int, mat: TexelMaterial,
              seed: int, refresh: int = 0, progress=None) -> PhotonHits:
        """Trace photons_per_source photons from every source (S, 3) with intensities (S, 3)."""
        sources = np.asarray(sources, dtype=np.float64).reshape(-1, 3)
        intensities = np.asarray(intensities, dtype=np.float64).reshape(-1, 3)
        S, N = len(sources), int(photons_per_source)
        units = [(s, a, min(a + CHUNK, N)) for s in range(S) for a in range(0, N, CHUNK)]
        results: list = [None] * len(units)
        done = [0]
        for s in range(S):                 # shadow rays of the landing densities, before the threads start
            self.landing(sources[s])
        if mat.q is None and self.lobe is not None:
            mat.q = specular_probability(self.lobe, mat.pd, mat.ps)

        def work(k: int) -> None:
            s, a, b = units[k]
            rng = np.random.default_rng([int(seed), 0x50, int(refresh), s, a // CHUNK])
            results[k] = self.trace_chunk(sources[s], intensities[s], b - a, N, mat, rng)
            done[0] += b - a
            if progress is not None:
                progress(done[0], S * N)

        if self.tracer.threads > 1 and len(units) > 1:
            with ThreadPoolExecutor(self.tracer.threads) as pool:
                list(pool.map(work, range(len(units))))
        else:
            for k in range(len(units)):
                work(k)
        src, tex, dirs, pw, em, kk = [], [], [], [], [], []
        rays = 0
        for (s, _, _), ((t, d, p, e, k), r) in zip(units, results):
            rays += r
            for a, b, c, f, g in zip(t, d, p, e, k):
                src.append(np.full(len(a), s, dtype=np.int64))
                tex.append(a)
                dirs.append(b)
                pw.append(c)
                em.append(f)
                kk.append(g)
        cat = lambda x, shape, dt: np.concatenate(x) if x else np.zeros(shape, dtype=dt)
        return PhotonHits(cat(src, (0,), np.int64), cat(tex, (0,), np.int64), cat(dirs, (0, 3), np.float64),
                          cat(pw, (0, 3), np.float64), np.full(S, N, dtype=np.int64), rays,
                          cat(em, (0,), np.int64), cat(kk, (0, 3), np.float64))
