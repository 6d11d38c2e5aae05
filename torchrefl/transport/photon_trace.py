"""Photon tracing with Embree (Method III, dissertation Ch.5): light paths from point lights over the surface's mesh.

Photons are aimed at the object: a photon of source s (position L, radiant intensity Y, RGB) first
lands on mesh face f with probability proportional to the face's direct flux geometry (drawn by
systematic sampling), at a uniform point of the face,
    a_f = A_f max(n_f.l, 0) vis_f / |L - c_f|^2          (at the centroid c_f; vis by an Embree shadow ray),
which is the density of a ray from L whose first hit is f, so every photon carries the same
    Phi = Y * sum_f a_f / N                              (N photons of that source),
and no photon is wasted on directions that miss. The first hit is not stored (direct light is computed analytically
by the local terms) and needs no ray: the photon starts on the face with wi = l (docs/results/reference_check.md:
why not from the texel vertex). Later hits are found with Embree; a hit's texel is the Surface's hit map's
(core/texel_hits.py: on the scan's range mesh the nearest mesh vertex, mesh vertices being texel grid points; on
a mesh's atlas the texel under the hit's uv). From the first hit on, the photon is scattered about the normal of
the face it is on (no photon re-enters the face it leaves, as the reference path tracer) by the current BRDF of
the texel it hit, g = f cos_l = g_diffuse + g_specular (torchrefl.core.brdf; non-reciprocal lobes are evaluated
with the light on the incident side, the way the fitter and the renderer use them), by one-sample component
selection: with probability q = mean(Ps) / (mean(Pd) + mean(Ps)) a direction wo from the specular lobe, otherwise
a cosine-weighted one, each with the weight of its own component
    w = g_c(n, l=wi, v=wo) cos(n, wo) / (cos(n, wi) P(c) pdf_c(wo))    (Pd / (1 - q) for the diffuse one),
then Russian roulette with survival s = min(0.95, max_c w) and Phi <- Phi w / s (PhotonTracer.scatter).
Every later hit on the front side of the mesh
(face normal, oriented like the texel normals, towards wi) is stored with the texel, the incident direction wi
(towards where the photon came from), Phi and the density weight max(n_t.wi, 0) / n_f.wi, which turns the flux
through the face into irradiance on the texel's normal n_t, the normal the model and the observations use
(next to a fold the faces around a texel are bent away from it); hits on the back of the scanned surface absorb the
photon (the unscanned side is not modelled).

Deterministic in `seed`: random numbers are keyed by (seed, refresh, source, chunk), never by thread.
The paths are traced in float32 (positions, directions, flux), as Embree intersects them; the cache
reductions (torchrefl.transport.cache_build) sum in float64.
"""

from __future__ import annotations

import numpy as np
import torch

from torchrefl.core import brdf as brdf_mod
from torchrefl.core.lobe_sampling import (
    LOBES,
    column_dot,
    lobe_over_pdf,
    lobe_theta,
    tangent_frame,
)
from torchrefl.core.point_light import point_light
from torchrefl.core.rays import RayTracer
from torchrefl.core.texel_hits import TexelHits
from torchrefl.core.threads import thread_map
from torchrefl.errors import GeometryError
from torchrefl.geometry.face_split import split_faces
from torchrefl.transport.photon_hits import PhotonHits
from torchrefl.transport.photon_material import ScatterTables, TexelMaterial
from torchrefl.transport.range_mesh_hits import RangeMeshHits

CHUNK = 1 << 17  # photons per work unit


def _take3(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Columns `index` of a component-major (3, N) array (np.take: several times faster than fancy indexing)."""
    return np.take(a, index, axis=1)


class PhotonTracer:
    """Photon tracing over the traced mesh of a Surface.

    Which texel a point of the mesh belongs to, each texel's collection area (the area whose hits its photon
    density divides by) and the faces' front sides come from hits (core/texel_hits.py, the Surface's `hits`):
    None, the scan's range mesh (transport/range_mesh_hits.RangeMeshHits: mesh vertex v is grid point v, a hit goes
    to the nearest corner, a texel collects a third of the faces around its vertex that lie along it); a mesh's
    atlas (geometry/atlas_hits.AtlasHits: the real mesh, a hit's uv gives its texel, a texel collects its own
    area).

    tracer: Embree scene of the mesh; texel_index, positions, normals: the Surface's; brdf: model name;
    hits: the Surface's hits (None: the range mesh of texel_index over the tracer's mesh); offset: origin offset
    along the normal for scattered rays (scene units); max_bounces: cap on the bounces after the first hit;
    min_bounces: bounces before Russian roulette starts. vertex_texel: (V,) texel at each mesh vertex on a range
    mesh (RangeMeshHits.vertex_texel), None on an atlas.
    """

    def __init__(
        self,
        tracer: RayTracer,
        texel_index: np.ndarray,
        positions: np.ndarray,
        normals: np.ndarray,
        brdf: str,
        *,
        hits: TexelHits | None = None,
        offset: float = 0.01,
        min_bounces: int = 1,
        max_bounces: int = 16,
    ):
        brdf_mod.check_brdf_name(brdf, "reflectance.brdf")
        if min_bounces < 0 or max_bounces < max(1, min_bounces):
            raise GeometryError(
                f"PhotonTracer min_bounces/max_bounces: need 0 <= min ({min_bounces}) <= max ({max_bounces}), max >= 1"
            )
        self.tracer = tracer
        self.brdf = brdf
        self.lobe = LOBES[brdf]
        self.positions = np.ascontiguousarray(positions, dtype=np.float64)
        self.normals = np.ascontiguousarray(normals, dtype=np.float64)
        self._landing: dict = {}
        self.offset = float(offset)
        self.min_bounces = int(min_bounces)
        self.max_bounces = int(max_bounces)
        faces = np.asarray(tracer.faces, dtype=np.int64)
        self.hits = RangeMeshHits(tracer.vertices, faces, texel_index, self.normals) if hits is None else hits
        if self.hits.num_faces != len(faces) or self.hits.num_texels != len(self.normals):
            raise GeometryError(
                f"photon tracing: the surface's hits cover {self.hits.num_faces} faces and {self.hits.num_texels} "
                f"texels, expected the traced mesh's {len(faces)} faces and the surface's {len(self.normals)} texels"
            )
        self.vertex_texel = getattr(self.hits, "vertex_texel", None)
        self.faces = faces
        self.frame_t, self.frame_b = tangent_frame(self.normals)
        verts = np.asarray(tracer.vertices, dtype=np.float64)
        fa = 0.5 * np.linalg.norm(
            np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]), axis=1
        )
        self.face_normals = self.hits.face_normals
        self.areas = self.hits.areas
        corners = verts[faces] if faces.size else np.zeros((0, 3, 3))
        # photons land on emission triangles: the faces, or where faces are larger than texels (an atlas: hits'
        # emission_size) the faces split to about that size, so that a_f at each one's centroid follows the light
        self._parent = self._parent_bary = None
        size = getattr(self.hits, "emission_size", None)
        if size is not None and faces.size:
            corners, self._parent, bary = split_faces(verts, faces, float(size))
            self._parent_bary = [np.ascontiguousarray(bary[:, c].T, dtype=np.float32) for c in range(3)]  # 3 x (3, E)
            fa = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
        self._face_area, self._centroids = fa, corners.mean(1) if faces.size else np.zeros((0, 3))
        self._landing_normals = self.face_normals if self._parent is None else self.face_normals[self._parent]
        self._corner3 = [np.ascontiguousarray(corners[:, c].T, dtype=np.float32) for c in range(3)]  # 3 x (3, E)
        # float32 copies for the hot path (Embree works in float32 anyway)
        f32 = lambda x: np.ascontiguousarray(np.asarray(x).T, dtype=np.float32)  # (3, N): component-major
        self._pos3, self._n3 = f32(self.positions), f32(self.normals)
        self._t3, self._b3, self._fn3 = f32(self.frame_t), f32(self.frame_b), f32(self.face_normals)
        self._ft3, self._fb3 = (f32(x) for x in tangent_frame(self.face_normals))
        self._offset32 = np.float32(self.offset)

    def landing(self, source: np.ndarray) -> np.ndarray:
        """(E,) a_f of the module docstring, per emission triangle (the mesh faces, or their split: __init__), for
        one source position (cached per position)."""
        key = tuple(np.round(np.asarray(source, dtype=np.float64), 9))
        if key not in self._landing:
            L = np.broadcast_to(np.asarray(source, dtype=np.float64), self._centroids.shape)
            self._landing[key] = self._face_area * (
                point_light(self._centroids, self._landing_normals, L, self.tracer, offset=self.offset).irradiance()
            )
        return self._landing[key]

    def emission_faces(self, element: np.ndarray) -> np.ndarray:
        """(N,) mesh face of each emission triangle element (N,) (landing's index)."""
        return element if self._parent is None else np.take(self._parent, element)

    def points_on(self, face: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Uniform points (3, N) float32 on emission triangles `face` (N,) (the mesh faces unless split: landing)
        and their texels (N,) (hits.texels)."""
        r1, r2 = rng.random((2, len(face)), dtype=np.float32)
        s1 = np.sqrt(r1)
        b = np.stack([1 - s1, s1 * (1 - r2), s1 * r2])  # (3, N) barycentric weights
        y = _take3(self._corner3[0], face) * b[0]
        y += _take3(self._corner3[1], face) * b[1]
        y += _take3(self._corner3[2], face) * b[2]
        if self._parent is None:
            return y, self.hits.texels(face, b)[0]
        pb = _take3(self._parent_bary[0], face) * b[0]  # the point's weights on its mesh face
        pb += _take3(self._parent_bary[1], face) * b[1]
        pb += _take3(self._parent_bary[2], face) * b[2]
        return y, self.hits.texels(np.take(self._parent, face), pb)[0]

    # ------------------------------------------------------------------ pieces

    def hit_texels(
        self, triangle: np.ndarray, u: np.ndarray, v: np.ndarray, direction: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(N,) texel of each hit on faces triangle (N,) at Embree's barycentrics u, v (N,) and (N,) bool whether
        the hit counts in that texel's density: hits.texels (on the range mesh the corner of the hit face with
        the largest barycentric weight, the first one on a tie). direction (3, N), the rays' directions:
        hits.seen_texels, the texel the ray sees (on the range mesh, on a face that bridges a fold or crease, the
        corner that faces the ray, fold_hits.facing_corner; the form factors apply the same rule): specular_gather's
        rays, which read the radiosity level's radiance. Photon hits take hits.texels, the region whose area
        collects them."""
        bary = np.stack([1 - u - v, u, v])
        if direction is None:
            return self.hits.texels(triangle, bary)
        return self.hits.seen_texels(triangle, bary, direction)

    def _frames(
        self, texel: np.ndarray, n: np.ndarray, own: np.ndarray | None, face: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Tangents (t, b), each (3, N), of the scattering normals n (3, N): the precomputed frame of the face
        (face given: n is its normal) or of the texel, a fresh one where the face normal stands in (own False)."""
        if face is not None:
            return _take3(self._ft3, face), _take3(self._fb3, face)
        t, b = _take3(self._t3, texel), _take3(self._b3, texel)
        if own is not None and not own.all():
            bad = np.flatnonzero(~own)
            tb = tangent_frame(n[:, bad].T.astype(np.float64))
            t[:, bad], b[:, bad] = tb[0].T, tb[1].T
        return t, b

    def scatter(
        self,
        texel,
        y,
        wi,
        n,
        cos_i,
        own,
        power,
        tables: "ScatterTables",
        u: np.ndarray,
        roulette: bool,
        path: np.ndarray | None = None,
        face: np.ndarray | None = None,
    ):
        """One scattering of N photons at texels `texel` (N,) int32, positions y (3, N), arriving along -wi
        (3, N), about normals n (3, N) with cos_i = n.wi > 0, own (N,) bool or None (n is the texel's normal),
        flux power (3, N), uniforms u (4, N) float32 (u[2] picks the component, u[3] plays the roulette).
        Returns the survivors' (origin (3, M), direction (3, M), power (3, M), diffuse_per_pd (3, M), emitter
        texel (M,), specular_path (M,) bool), float32 / int32 (vectors are stored component-major: numpy's fast
        layout for them); path (N,) bool: the photons' specular_path flags before this scattering (None: all False),
        which a survivor keeps after a diffuse scattering and sets after a specular one; face (N,): n is that mesh
        face's normal (its precomputed tangent frame), or None.

        One-sample component selection: with probability q_t the specular lobe, otherwise the cosine
        distribution, each weighted by its own part of the BRDF over its own pdf (unbiased, since
        g = g_diffuse + g_specular). Diffuse: w = Pd / (1 - q), and diffuse_per_pd = Phi / (1 - q) (all of it is
        linear in the scattering texel's Pd); the direction is n plus a uniform point on the unit sphere,
        normalised (cosine-distributed about n, no tangent frame needed). Specular: a half vector h from the
        lobe, wo = reflect(wi, h), w = Ps D G cos_o / (cos_i q p(wo)) with p(wo) = p_h / (4 |wi.h|) and D / p_h
        in closed form (lobe_sampling.lobe_over_pdf); diffuse_per_pd = 0. Russian roulette (when `roulette`):
        survival s = min(0.95, max_c w), Phi <- Phi w / s; otherwise only photons with w = 0 stop."""
        spec = u[2] < np.take(tables.q, texel)
        path = np.zeros(len(texel), dtype=bool) if path is None else path
        surv, w_d, k_d = tables.diffuse(roulette)
        parts = []
        iD = np.flatnonzero(~spec & (u[3] < np.take(surv, texel)))
        if iD.size:
            parts.append(self._scatter_diffuse(iD, texel, y, n, power, w_d, k_d, u, path))
        iS = np.flatnonzero(spec) if self.lobe is not None and spec.any() else np.zeros(0, np.int64)
        if iS.size:
            part = self._scatter_specular(iS, texel, y, wi, n, cos_i, own, power, tables, u, roulette, face)
            if part is not None:
                parts.append(part)
        if len(parts) == 1:
            return parts[0]
        if not parts:
            empty = np.zeros((3, 0), np.float32)
            return empty, empty, empty, empty, np.zeros(0, np.int32), np.zeros(0, bool)
        return tuple(np.concatenate([p[j] for p in parts], axis=-1) for j in range(6))

    def _scatter_diffuse(self, iD, texel, y, n, power, w_d, k_d, u, path) -> tuple:
        """scatter's diffuse branch for the photons iD (all survive): cosine-distributed directions about n
        (n plus a uniform point on the unit sphere, normalised), weight w_d, per-unit-Pd weight k_d of the
        texel (ScatterTables.diffuse); the photons keep their specular_path flags."""
        tD, nD = np.take(texel, iD), _take3(n, iD)
        z = 1 - 2 * np.take(u[0], iD)
        r = np.sqrt(np.maximum(1 - z * z, 0))
        phi = np.float32(2 * np.pi) * np.take(u[1], iD)
        d = nD + np.stack([r * np.cos(phi), r * np.sin(phi), z])
        d /= np.maximum(np.sqrt(column_dot(d, d)), np.float32(1e-12))
        pw = _take3(power, iD)
        return (
            _take3(y, iD) + self._offset32 * nD,
            d,
            pw * _take3(w_d, tD),
            pw * np.take(k_d, tD),
            tD,
            np.take(path, iD),
        )

    def _scatter_specular(self, iS, texel, y, wi, n, cos_i, own, power, tables, u, roulette, face) -> tuple | None:
        """scatter's specular branch for the photons iS: a half vector from the lobe, wo = reflect(wi, h), the
        weight Ps D G cos_o / (cos_i q p(wo)) and the roulette; the survivors' part (specular_path set), or None
        when none survives."""
        tS, nS, wiS = np.take(texel, iS), _take3(n, iS), _take3(wi, iS)
        own_s, face_s = (None if x is None else np.take(x, iS) for x in (own, face))
        fa, fb = self._frames(tS, nS, own_s, face_s)
        theta = lobe_theta(self.lobe, np.take(tables.sigma, tS), np.take(u[0], iS), np.take(tables.truncation, tS))
        st, ct = np.sin(theta), np.cos(theta)
        phi = np.float32(2 * np.pi) * np.take(u[1], iS)
        h = fa * (st * np.cos(phi))
        h += fb * (st * np.sin(phi))
        h += nS * ct
        vh = column_dot(wiS, h)
        wo = 2 * vh * h - wiS
        ci = np.take(cos_i, iS)
        cos_o = 2 * vh * ct - ci  # n.wo, since n.h = cos(theta)
        with torch.no_grad():
            g_cos = (
                brdf_mod.specular_geometry(self.brdf, torch.from_numpy(ci), torch.from_numpy(cos_o))
                * torch.from_numpy(np.maximum(cos_o, 0))
            ).numpy()
        ws = lobe_over_pdf(self.lobe, theta, ct, st, np.take(tables.ratio_scale, tS)) * (4 * np.abs(vh)) * g_cos
        # cos_i > 0 here; the floor only bounds the weight of photons grazing a face whose normal stood in
        ws /= np.maximum(ci, np.float32(1e-6)) * np.take(tables.q, tS)
        top = np.take(tables.ps_max, tS) * ws
        if roulette:
            s = np.minimum(np.float32(0.95), top)
            live = np.flatnonzero(np.take(u[3], iS) < s)
        else:
            s = np.ones_like(top)
            live = np.flatnonzero(top > 0)
        if not live.size:
            return None
        i, tl = np.take(iS, live), np.take(tS, live)
        pw = _take3(power, i) * _take3(tables.ps, tl) * (np.take(ws, live) / np.take(s, live))
        return (
            _take3(y, i) + self._offset32 * _take3(nS, live),
            _take3(wo, live),
            pw,
            np.zeros_like(pw),
            tl,
            np.ones(live.size, dtype=bool),
        )

    # ------------------------------------------------------------------ paths

    def trace_chunk(
        self,
        source: np.ndarray,
        intensity: np.ndarray,
        n: int,
        n_total: int,
        tables: "ScatterTables",
        rng: np.random.Generator,
        specular_paths_only: bool = False,
    ) -> tuple[list, int]:
        """n photons of one source (out of n_total for that source); returns ([(texel, wi (3, M), power (3, M),
        emitter, diffuse_per_pd (3, M), collects, specular_path, density_weight) per bounce], rays, back-side hits),
        float32 / int32 arrays; specular_paths_only: a bounce keeps only its hits whose path had a specular
        scattering."""
        a = self.landing(source)
        total = float(a.sum())
        stored: list = []
        if total <= 0:
            return stored, 0, 0
        # systematic sampling: n stratified positions on the cdf (lower variance than independent draws, O(F + n),
        # and the photons come out ordered by face, which keeps the rays coherent)
        edges = np.floor(np.concatenate([[0.0], np.cumsum(a / total)]) * n + rng.random())
        face = np.repeat(np.arange(len(a), dtype=np.int64), np.diff(edges).astype(np.int64))
        y, texel = self.points_on(face, rng)
        face = self.emission_faces(face)
        wi = np.asarray(source, dtype=np.float32)[:, None] - y
        wi /= np.sqrt(column_dot(wi, wi))
        power = np.repeat((intensity * (total / n_total)).astype(np.float32)[:, None], len(texel), 1)
        n_s = _take3(self._fn3, face)  # scattered about the face normal
        cos_i = column_dot(n_s, wi)
        origin = d = per_pd = emitter = None  # the rays of the previous bounce and their photons
        path = np.zeros(len(texel), dtype=bool)  # no scattering yet: the first hit is the direct light
        rays = back = 0
        for depth in range(self.max_bounces + 1):
            if depth > 0:
                # work units run on tracer.threads threads; a unit's rays go through Embree on its own thread
                prim, bu, bv, dist = self.tracer.first_hits(np.stack(tuple(origin), -1), np.stack(tuple(d), -1))
                rays += origin.shape[1]
                # hits on the front (towards the photon) of the mesh only: the back of the scanned surface absorbs
                front = (prim >= 0) & (column_dot(_take3(self._fn3, np.maximum(prim, 0)), d) < 0)
                k = np.flatnonzero(front)
                back += int(np.count_nonzero(prim >= 0)) - k.size
                if not k.size:
                    break
                prim = np.take(prim, k)
                dk = _take3(d, k)
                # the nearest corner, whose texel's collecting area holds the hit (not fold_hits' rule: +37 % at a fold)
                texel, collects = self.hit_texels(prim, np.take(bu, k), np.take(bv, k))
                y = _take3(origin, k) + np.take(dist, k) * dk
                wi = -dk
                power, per_pd, emitter, path = (
                    _take3(power, k),
                    _take3(per_pd, k),
                    np.take(emitter, k),
                    np.take(path, k),
                )
                n_s = _take3(self._fn3, prim)  # the face's normal: n_s.wi > 0 on the front
                cos_i = column_dot(n_s, wi)
                face = prim
                weight = np.maximum(column_dot(_take3(self._n3, texel), wi), 0) / np.maximum(cos_i, np.float32(1e-6))
                stored.append(_stored(texel, wi, power, emitter, per_pd, collects, path, weight, specular_paths_only))
            if depth == self.max_bounces:
                break
            u = rng.random((4, len(texel)), dtype=np.float32)
            origin, d, power, per_pd, emitter, path = self.scatter(
                texel, y, wi, n_s, cos_i, None, power, tables, u, depth + 1 > self.min_bounces, path=path, face=face
            )
            if not d.shape[1]:
                break
        return stored, rays, back

    def trace(
        self,
        sources: np.ndarray,
        intensities: np.ndarray,
        photons_per_source: int,
        mat: TexelMaterial,
        seed: int,
        refresh: int = 0,
        progress=None,
        specular_paths_only: bool = False,
    ) -> PhotonHits:
        """Trace photons_per_source photons from every source (S, 3) with intensities (S, 3). specular_paths_only:
        store only the hits whose path had a specular scattering (for a cache that takes the all-diffuse paths from
        the radiosity level and gathers their specular reflection: build_cache(diffuse_paths=False,
        specular_paths_only=True) gives the other hits no weight); the photons are traced as without it."""
        sources = np.asarray(sources, dtype=np.float64).reshape(-1, 3)
        intensities = np.asarray(intensities, dtype=np.float64).reshape(-1, 3)
        S, N = len(sources), int(photons_per_source)
        units = [(s, a, min(a + CHUNK, N)) for s in range(S) for a in range(0, N, CHUNK)]
        results: list = [None] * len(units)
        done = [0]
        for s in range(S):  # shadow rays of the landing densities, before the threads start
            self.landing(sources[s])
        tables = ScatterTables.build(self.lobe, mat)

        def work(k: int) -> None:
            s, a, b = units[k]
            rng = np.random.default_rng([int(seed), 0x50, int(refresh), s, a // CHUNK])
            results[k] = self.trace_chunk(sources[s], intensities[s], b - a, N, tables, rng, specular_paths_only)
            done[0] += b - a
            if progress is not None:
                progress(done[0], S * N)

        thread_map(work, range(len(units)), self.tracer.threads)
        rays = sum(r[1] for r in results)
        back = sum(r[2] for r in results)
        batches = [(s, b) for (s, _, _), (stored, _, _) in zip(units, results) for b in stored]
        if not batches:
            return PhotonHits(
                np.zeros(0, np.int64),
                np.zeros(0, np.int64),
                np.zeros((0, 3), np.float32),
                np.zeros((0, 3), np.float32),
                np.full(S, N, dtype=np.int64),
                rays,
                np.zeros(0, np.int64),
                np.zeros((0, 3), np.float32),
                back_hits=back,
                specular_path=np.zeros(0, dtype=bool),
                density_weight=np.zeros(0, dtype=np.float32),
            )
        # the bounces' arrays field by field, each field's batches let go once gathered (not all alive to the end)
        source = np.concatenate([np.full(len(b[0]), s, dtype=np.int64) for s, b in batches])
        fields = [list(f) for f in zip(*(b for _, b in batches))]
        batches = results = None
        keep = np.flatnonzero(np.concatenate(fields[5]))
        fields[5] = None

        def gather(j: int, axis: int = 0) -> np.ndarray:
            part, fields[j] = fields[j], None
            return np.take(np.concatenate(part, axis=axis), keep, axis=axis)

        source = np.take(source, keep)
        ints = lambda j: gather(j).astype(np.int64)
        vecs = lambda j: gather(j, axis=1).T  # (N, 3) views
        return PhotonHits(
            source,
            ints(0),
            vecs(1),
            vecs(2),
            np.full(S, N, dtype=np.int64),
            rays,
            ints(3),
            vecs(4),
            back_hits=back,
            specular_path=gather(6),
            density_weight=gather(7),
        )


def _stored(texel, wi, power, emitter, per_pd, collects, path, weight, specular_paths_only: bool) -> tuple:
    """A bounce's stored arrays (trace_chunk's tuple); specular_paths_only: only the hits whose path had a specular
    scattering (the others' arrays cut before they are kept)."""
    if not specular_paths_only:
        return texel, wi, power, emitter, per_pd, collects, path, weight
    k = np.flatnonzero(path & collects)
    cut = lambda a: np.take(a, k, axis=-1)  # noqa: E731 (the vectors are component-major (3, M))
    return tuple(cut(a) for a in (texel, wi, power, emitter, per_pd, collects, path, weight))
