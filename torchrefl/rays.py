"""The one Embree boundary (embreex): closest-hit and occlusion queries, origin offsets, batching, threads.

Everything that traces rays goes through RayTracer. Embree's tnear is fixed at 0, so callers
that start rays on a surface offset the origin along the normal (`visible` does it). Large
batches are split into chunks and run on a thread pool: embreex releases the GIL inside
scene.run, and a committed Embree scene may be queried from several threads at once.
Arrays are numpy; Embree works in float32, distances come back as float64.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh

from torchrefl.errors import GeometryError

_FAR = 1e37


@dataclass
class Hits:
    """Closest hits: distance (N,) float64 (inf on miss), along unit directions; triangle (N,) int64
    (-1 on miss); barycentric (N, 2) float64 (Embree's u, v; NaN on miss); hit (N,) bool."""

    distance: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    hit: np.ndarray


def _rays(name: str, a, n: int | None = None) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[1] != 3:
        raise GeometryError(f"{name} has shape {a.shape}, expected (N, 3)")
    if n is not None and a.shape[0] != n:
        raise GeometryError(f"{name} has {a.shape[0]} rows, expected {n} like origins")
    if not np.isfinite(a).all():
        raise GeometryError(f"{name} contains NaN or inf values ({int((~np.isfinite(a)).any(1).sum())} rays)")
    return a if a.dtype in (np.float32, np.float64) else a.astype(np.float64)


def _unit_rays(origins, directions) -> tuple[np.ndarray, np.ndarray]:
    """Checked float32 origins and unit directions (N, 3)."""
    o = _rays("origins", origins)
    d = _rays("directions", directions, len(o))
    norm = np.linalg.norm(d, axis=1)
    if (norm == 0).any():
        raise GeometryError(f"directions has {int((norm == 0).sum())} zero-length rays")
    return o.astype(np.float32), (d / norm[:, None]).astype(np.float32)


class RayTracer:
    """Embree scene over one triangle mesh.

    vertices: (V, 3) float; faces: (F, 3) int indices into vertices.
    threads: worker threads for large batches; chunk_size: rays per Embree call.
    """

    def __init__(self, vertices, faces, *, threads: int = 2, chunk_size: int = 1 << 20):
        v = np.asarray(vertices)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3:
            raise GeometryError(f"mesh vertices have shape {v.shape}, expected (V, 3)")
        if f.ndim != 2 or f.shape[1] != 3:
            raise GeometryError(f"mesh faces have shape {f.shape}, expected (F, 3)")
        if len(f) == 0 or len(v) == 0:
            raise GeometryError("mesh is empty (no vertices or no faces): nothing to trace rays against")
        if not np.isfinite(v).all():
            raise GeometryError("mesh vertices contain NaN or inf values")
        if f.min() < 0 or f.max() >= len(v):
            raise GeometryError(f"mesh faces index vertices out of range 0..{len(v) - 1}")
        self.vertices = np.ascontiguousarray(v, dtype=np.float32)
        self.faces = np.ascontiguousarray(f, dtype=np.int32)
        self.scene = rtcs.EmbreeScene()
        self._mesh = TriangleMesh(self.scene, self.vertices, self.faces)
        self.threads = max(1, int(threads))
        self.chunk_size = max(1, int(chunk_size))

    @property
    def num_triangles(self) -> int:
        return int(len(self.faces))

    def _map(self, fn, n: int):
        """Run fn(start, stop) over chunks of [0, n), on threads when there is more than one chunk."""
        bounds = [(s, min(s + self.chunk_size, n)) for s in range(0, n, self.chunk_size)]
        if self.threads == 1 or len(bounds) == 1:
            for b in bounds:
                fn(*b)
            return
        with ThreadPoolExecutor(self.threads) as pool:
            list(pool.map(lambda b: fn(*b), bounds))

    def closest_hit(self, origins, directions, max_distance=None) -> Hits:
        of, du = _unit_rays(origins, directions)
        n = len(of)
        far = np.full(n, _FAR, dtype=np.float32) if max_distance is None else np.broadcast_to(
            np.asarray(max_distance, dtype=np.float32), (n,)).copy()
        dist = np.full(n, np.inf)
        tri = np.full(n, -1, dtype=np.int64)
        bary = np.full((n, 2), np.nan)

        def work(a, b):
            res = self.scene.run(of[a:b], du[a:b], dists=far[a:b].copy(), query="INTERSECT", output=1)
            prim = res["primID"].astype(np.int64)
            ok = prim >= 0
            tri[a:b] = prim
            dist[a:b] = np.where(ok, res["tfar"], np.inf)
            bary[a:b, 0] = np.where(ok, res["u"], np.nan)
            bary[a:b, 1] = np.where(ok, res["v"], np.nan)

        if n:
            self._map(work, n)
        return Hits(dist, tri, bary, tri >= 0)

    def occluded(self, origins, directions, max_distance) -> np.ndarray:
        """(N,) bool: some triangle is hit at 0 < t < max_distance along the (normalised) direction."""
        of, du = _unit_rays(origins, directions)
        far = np.broadcast_to(np.asarray(max_distance, dtype=np.float64), (len(of),))
        if np.isnan(far).any():
            raise GeometryError("max_distance contains NaN values")
        return self._occluded32(of, du, far)

    def visible(self, points, normals, targets, *, offset: float) -> np.ndarray:
        """(N,) bool: the segment from each surface point to its target is unblocked.

        The origin moves by `offset` along the normal flipped to the target's side (or along the
        segment when normals is None), and the segment is shortened by `offset` at the target end.
        Computed in float32, like Embree.
        """
        p = _rays("points", points).astype(np.float32, copy=False)
        t = _rays("targets", targets, len(p)).astype(np.float32, copy=False)
        seg = t - p
        if normals is None:
            length = np.sqrt(np.einsum("ni,ni->n", seg, seg))
            origin = p + (offset / np.maximum(length, 1e-30))[:, None] * seg
        else:
            nrm = _rays("normals", normals, len(p)).astype(np.float32, copy=False)
            side = np.where(np.einsum("ni,ni->n", nrm, seg) >= 0, offset, -offset).astype(np.float32)
            origin = p + side[:, None] * nrm
        seg2 = t - origin
        dist = np.sqrt(np.einsum("ni,ni->n", seg2, seg2))
        vis = np.ones(len(p), dtype=bool)
        ok = dist > offset
        if ok.all():
            return ~self._occluded32(origin, seg2 / dist[:, None], dist - offset)
        if ok.any():
            idx = np.flatnonzero(ok)
            vis[idx] = ~self._occluded32(origin[idx], seg2[idx] / dist[idx, None], dist[idx] - offset)
        return vis

    def _occluded32(self, origins: np.ndarray, unit_dirs: np.ndarray, far: np.ndarray) -> np.ndarray:
        """Occlusion for already checked float32 origins and unit directions."""
        n = len(origins)
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(unit_dirs, dtype=np.float32)
        f = np.minimum(far, _FAR).astype(np.float32)
        out = np.zeros(n, dtype=bool)

        def work(a, b):
            out[a:b] = np.asarray(self.scene.run(o[a:b], d[a:b], dists=f[a:b].copy(), query="OCCLUDED")) >= 0

        if n:
            self._map(work, n)
        return out


def raw_embree_rate(vertices, faces, n_rays: int, query: str, seed: int = 0) -> float:
    """Rays/s of one bare single-threaded scene.run call on random rays aimed at the mesh (no wrapper):
    the reference that benchmarks divide by. query: 'INTERSECT' or 'OCCLUDED'."""
    v = np.ascontiguousarray(vertices, dtype=np.float32)
    scene = rtcs.EmbreeScene()
    TriangleMesh(scene, v, np.ascontiguousarray(faces, dtype=np.int32))
    rng = np.random.default_rng(seed)
    centre = v.mean(0)
    radius = float(np.linalg.norm(v - centre, axis=1).max()) * 2.0
    dirs = rng.normal(size=(n_rays, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origins = (centre - radius * dirs + rng.normal(scale=0.1 * radius, size=(n_rays, 3))).astype(np.float32)
    dirs = dirs.astype(np.float32)
    dists = np.full(n_rays, 4 * radius, dtype=np.float32)
    start = time.perf_counter()
    if query == "INTERSECT":
        scene.run(origins, dirs, dists=dists, query="INTERSECT", output=1)
    else:
        scene.run(origins, dirs, dists=dists, query="OCCLUDED")
    return n_rays / (time.perf_counter() - start)
