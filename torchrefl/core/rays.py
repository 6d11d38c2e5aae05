"""The one Embree boundary (embreex): closest-hit and occlusion queries, origin offsets, batching, threads.

Everything that traces rays goes through RayTracer. Arrays are numpy in and numpy out; float64 or
float32 input is accepted and handed to Embree as contiguous float32; distances come back as float64.

Facts about embreex 4 this module relies on (checked against the installed build):

- `scene.run(origins, dirs, dists=far, query="INTERSECT", output=1)` returns a dict of float32 `u`,
  `v`, `tfar`, `Ng` (unnormalised geometric normal) and int32 `primID`, `geomID` (-1 on a miss; `tfar`
  is then the far value passed in). `query="OCCLUDED"` must be called with output=0: it returns int32
  (0 = occluded, -1 = free); with output=1 it returns uninitialised memory.
- Embree overwrites the `dists` array in place with the hit distance, and reads it without bounds
  checks: every call gets a fresh float32 copy of exactly N values.
- `tnear` is fixed at 0, so a hit at t = 0 counts: rays that start on a surface must have their origin
  offset by the caller (`visible` does it).
- The scene's BVH is built lazily by the first `run` call (embreex's `is_committed` flag). RayTracer
  triggers that build once in its constructor, on one thread; after the commit Embree documents ray
  queries on a scene as thread safe, and `run` releases the GIL, so chunks of one batch run on a
  thread pool against the one shared scene.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh

from torchrefl.core.threads import thread_map
from torchrefl.errors import ConfigError, GeometryError

_FAR = 1e37  # "no limit" for Embree's float32 tfar
_BLOCK = 65536  # rays per Embree call at most: a block's float32 copies and outputs stay in cache
_MIN_SPLIT = 4096  # a batch is split over threads only into chunks of at least this many rays


@dataclass
class Hits:
    """Closest hits of N rays.

    distance: (N,) float64, distance to the hit along the unit ray direction (the Euclidean distance
        from the origin), inf on a miss.
    triangle: (N,) int64, index of the hit face, -1 on a miss.
    barycentric: (N, 2) float64, Embree's (u, v): hit = (1-u-v) v0 + u v1 + v v2; NaN on a miss.
    hit: (N,) bool.
    """

    distance: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    hit: np.ndarray


def _check_rays(name: str, a, n: int | None = None) -> np.ndarray:
    """Shape check only; values (NaN, inf, zero length) are checked per chunk in float32."""
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[1] != 3:
        raise GeometryError(f"{name} has shape {a.shape}, expected (N, 3)")
    if n is not None and a.shape[0] != n:
        raise GeometryError(f"{name} has {a.shape[0]} rows, expected {n} (one per ray, like origins)")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise GeometryError(f"{name} has dtype {a.dtype}, expected float")
    return a


def _check_far(name: str, value, n: int):
    """max_distance: scalar or (N,), >= 0, no NaN; inf means unlimited. Returns float32 scalar or (N,)."""
    f = np.asarray(value, dtype=np.float64) if value is not None else np.float64(np.inf)
    if f.ndim > 1 or (f.ndim == 1 and f.shape[0] != n):
        raise GeometryError(f"{name} has shape {f.shape}, expected a scalar or ({n},)")
    if np.isnan(f).any() or (f < 0).any():
        raise GeometryError(f"{name} contains NaN or negative values, expected distances >= 0")
    return np.minimum(f, _FAR).astype(np.float32)


def _finite32(name: str, a: np.ndarray, start: int) -> np.ndarray:
    """Contiguous float32 copy (or view) of a chunk; NaN/inf (also float64 beyond float32 range) rejected."""
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(a, dtype=np.float32)
    if not np.isfinite(out).all():
        first = int(np.flatnonzero(~np.isfinite(out).all(axis=1))[0])
        raise GeometryError(
            f"{name} contains NaN or inf values (or values beyond float32 range), first at row {start + first}"
        )
    return out


def _unit32(name: str, d: np.ndarray, start: int) -> np.ndarray:
    """Float32 unit directions of a chunk; zero-length directions rejected."""
    with np.errstate(over="ignore"):
        out = np.array(d, dtype=np.float32)
    if not np.isfinite(out).all():
        _finite32(name, out, start)
    norm = np.sqrt(np.einsum("ni,ni->n", out, out))
    if not (norm > 0).all():
        first = int(np.flatnonzero(~(norm > 0))[0])
        raise GeometryError(f"{name} has zero-length vectors, first at row {start + first}")
    out /= norm[:, None]
    return out


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Checked contiguous float32 (V, 3) vertices and int32 (F, 3) faces."""
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise GeometryError(f"mesh vertices have shape {v.shape}, expected (V, 3)")
    if f.ndim != 2 or f.shape[1] != 3:
        raise GeometryError(f"mesh faces have shape {f.shape}, expected (F, 3)")
    if len(f) == 0 or len(v) == 0:
        raise GeometryError("mesh is empty (no vertices or no faces): nothing to trace rays against")
    if not np.issubdtype(f.dtype, np.integer):
        raise GeometryError(f"mesh faces have dtype {f.dtype}, expected integer vertex indices")
    v32 = np.ascontiguousarray(v, dtype=np.float32)
    if not np.isfinite(v32).all():
        raise GeometryError("mesh vertices contain NaN or inf values (or values beyond float32 range)")
    if f.min() < 0 or f.max() >= len(v):
        raise GeometryError(f"mesh faces index vertices {f.min()}..{f.max()}, out of range 0..{len(v) - 1}")
    return v32, np.ascontiguousarray(f, dtype=np.int32)


def _scene(vertices32: np.ndarray, faces32: np.ndarray) -> rtcs.EmbreeScene:
    """A committed Embree scene (the BVH is built here, by one single-ray query)."""
    scene = rtcs.EmbreeScene()
    TriangleMesh(scene, vertices32, faces32)
    scene.run(
        np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32), dists=np.ones(1, np.float32), query="OCCLUDED"
    )
    return scene


class RayTracer:
    """Embree scene over one triangle mesh, built once and shared by all queries and threads.

    vertices: (V, 3) float; faces: (F, 3) int indices into vertices.
    threads: worker threads per query (each runs whole chunks through Embree).
    chunk_size: at most this many rays per Embree call. A batch of N rays is cut into chunks of
        min(chunk_size, 65536, max(4096, ceil(N / threads))) rays, which the threads take in turn:
        large batches use every thread, and each chunk's float32 copies stay in cache (chunks of 64k
        rays run as fast as one bare call on the whole batch; 1M-ray chunks cost ~15% more).
    Results do not depend on threads or chunk_size.
    """

    def __init__(self, vertices, faces, *, threads: int = 2, chunk_size: int = 1 << 20):
        if int(threads) < 1 or int(chunk_size) < 1:
            raise ConfigError(f"RayTracer threads={threads}, chunk_size={chunk_size}: expected both >= 1")
        self.vertices, self.faces = _check_mesh(vertices, faces)
        self.scene = _scene(self.vertices, self.faces)
        self.threads = int(threads)
        self.chunk_size = int(chunk_size)

    @property
    def num_triangles(self) -> int:
        return int(len(self.faces))

    def _map(self, fn: Callable[[int, int], None], n: int, threads: int | None = None) -> None:
        """Run fn(start, stop) over chunks of [0, n), by thread_map on `threads` threads (default self.threads)."""
        threads = self.threads if threads is None else max(1, int(threads))
        size = min(self.chunk_size, _BLOCK, max(_MIN_SPLIT, math.ceil(n / threads)))
        thread_map(lambda b: fn(*b), [(s, min(s + size, n)) for s in range(0, n, size)], threads)

    def first_hit_triangles(self, origins32: np.ndarray, directions32: np.ndarray) -> np.ndarray:
        """(N,) int64 index of the first triangle each ray hits (-1 for a miss), in one Embree call on the
        calling thread: the fast path for callers that generate their own rays and thread over work units.

        origins32, directions32: (N, 3) C-contiguous float32, finite, directions non-zero (not checked here:
        use closest_hit for rays from outside)."""
        return self.scene.run(origins32, directions32, query="INTERSECT").astype(np.int64)

    def first_hits(
        self, origins32: np.ndarray, directions32: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest hits in one Embree call on the calling thread, as Embree returns them: (triangle (N,) int32,
        -1 on a miss; u, v (N,) float32 barycentrics; t (N,) float32 distance along the unit direction,
        undefined on a miss). The photon tracer's fast path (it makes its own float32 rays and threads over work
        units); same preconditions as first_hit_triangles, and directions32 must be unit vectors."""
        res = self.scene.run(
            origins32, directions32, dists=np.full(len(origins32), _FAR, np.float32), query="INTERSECT", output=1
        )
        return res["primID"], res["u"], res["v"], res["tfar"]

    def closest_hit(self, origins, directions, max_distance=None, threads: int | None = None) -> Hits:
        """Nearest hit of each ray at 0 <= t <= max_distance.

        threads: worker threads for this call (default self.threads; 1 inside a caller's own thread pool).

        origins: (N, 3) float. directions: (N, 3) float, any nonzero length: they are normalised, and
        distances (and max_distance) are measured along the unit direction, i.e. Euclidean distances.
        max_distance: None (unlimited), a scalar or (N,) float >= 0.
        """
        o = _check_rays("origins", origins)
        d = _check_rays("directions", directions, len(o))
        n = len(o)
        far = _check_far("max_distance", max_distance, n)
        dist = np.empty(n)
        tri = np.empty(n, dtype=np.int64)
        bary = np.empty((n, 2))

        def work(a: int, b: int) -> None:
            o32 = _finite32("origins", o[a:b], a)
            d32 = _unit32("directions", d[a:b], a)
            f32 = np.full(b - a, far, np.float32) if far.ndim == 0 else far[a:b]  # our copy: Embree overwrites it
            res = self.scene.run(o32, d32, dists=f32, query="INTERSECT", output=1)
            prim = res["primID"]
            miss = prim < 0
            tri[a:b] = prim
            dist[a:b] = res["tfar"]
            bary[a:b, 0] = res["u"]
            bary[a:b, 1] = res["v"]
            if miss.any():
                dist[a:b][miss] = np.inf
                bary[a:b][miss] = np.nan
                tri[a:b][miss] = -1

        if n:
            self._map(work, n, threads)
        return Hits(dist, tri, bary, tri >= 0)

    def occluded(self, origins, directions, max_distance) -> np.ndarray:
        """(N,) bool: some triangle is hit at 0 <= t < max_distance along the normalised direction
        (Embree's OCCLUDED query; t is the Euclidean distance from the origin).

        origins, directions: (N, 3) float (directions any nonzero length). max_distance: scalar or (N,) >= 0.
        """
        o = _check_rays("origins", origins)
        d = _check_rays("directions", directions, len(o))
        return self._occluded(o, d, _check_far("max_distance", max_distance, len(o)), unit=False)

    def visible(self, points, normals, targets, *, offset: float) -> np.ndarray:
        """(N,) bool: the segment from each surface point to its target is unblocked.

        points, targets: (N, 3) float. normals: (N, 3) float (normalised here, either orientation) or None.
        offset: distance >= 0 (scene units). The origin moves by `offset` along the normal flipped to the
        target's side (n.(target - point) >= 0), or along the segment when normals is None; the segment
        is then shortened by `offset` at the target end, so surfaces at the target do not block either.
        A target within about 2 * offset of its point counts as visible (nothing is traced).
        Computed in float32, like Embree.
        """
        if not np.isscalar(offset) or not math.isfinite(offset) or offset < 0:
            raise GeometryError(f"visible offset is {offset!r}, expected a finite scalar >= 0")
        p = _finite32("points", _check_rays("points", points), 0)
        t = _finite32("targets", _check_rays("targets", targets, len(p)), 0)
        off = np.float32(offset)
        seg = t - p
        if normals is None:
            length = np.sqrt(np.einsum("ni,ni->n", seg, seg))
            origin = p + (off / np.maximum(length, np.float32(1e-30)))[:, None] * seg
        else:
            nrm = _unit32("normals", _check_rays("normals", normals, len(p)), 0)
            side = np.where(np.einsum("ni,ni->n", nrm, seg) >= 0, off, -off)
            origin = p + side[:, None] * nrm
        seg2 = t - origin
        dist = np.sqrt(np.einsum("ni,ni->n", seg2, seg2))
        far = dist - off
        vis = np.ones(len(p), dtype=bool)
        idx = np.flatnonzero(far > 0)
        if idx.size == len(p):
            return ~self.occluded_unit(origin, seg2 / dist[:, None], far)
        if idx.size:
            vis[idx] = ~self.occluded_unit(origin[idx], seg2[idx] / dist[idx, None], far[idx])
        return vis

    def occluded_unit(self, origins: np.ndarray, unit_dirs: np.ndarray, far: np.ndarray) -> np.ndarray:
        """(N,) bool occlusion for callers that already hold checked, finite float32 origins and unit
        directions (N, 3) and distances far (N,) > 0 (the hot path of light selection: no re-validation)."""
        return self._occluded(origins, unit_dirs, np.minimum(far, _FAR).astype(np.float32), unit=True)  # a copy

    def _occluded(self, o: np.ndarray, d: np.ndarray, far: np.ndarray, *, unit: bool) -> np.ndarray:
        """OCCLUDED query; far: float32 scalar or (N,) array owned by this call (Embree may write to it)."""
        n = len(o)
        out = np.empty(n, dtype=bool)

        def work(a: int, b: int) -> None:
            if unit:
                o32 = np.ascontiguousarray(o[a:b], dtype=np.float32)
                d32 = np.ascontiguousarray(d[a:b], dtype=np.float32)
            else:
                o32 = _finite32("origins", o[a:b], a)
                d32 = _unit32("directions", d[a:b], a)
            f32 = np.full(b - a, far, np.float32) if far.ndim == 0 else far[a:b]  # our float32 copy
            out[a:b] = self.scene.run(o32, d32, dists=f32, query="OCCLUDED") >= 0

        if n:
            self._map(work, n)
        return out


def aimed_rays(vertices, n_rays: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random rays aimed at a mesh, for benchmarks: float32 origins (n, 3) on a sphere of twice the
    mesh's radius (jittered), unit directions (n, 3) towards the mesh's centre region, far (n,) that
    reaches past the mesh."""
    v = np.asarray(vertices, dtype=np.float64)
    rng = np.random.default_rng(seed)
    centre = v.mean(0)
    radius = float(np.linalg.norm(v - centre, axis=1).max()) * 2.0
    dirs = rng.normal(size=(n_rays, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origins = centre - radius * dirs + rng.normal(scale=0.1 * radius, size=(n_rays, 3))
    return (origins.astype(np.float32), dirs.astype(np.float32), np.full(n_rays, 4 * radius, dtype=np.float32))


def raw_embree_rate(vertices, faces, n_rays: int, query: str, seed: int = 0) -> float:
    """Rays/s of one bare single-threaded scene.run call on `aimed_rays(vertices, n_rays, seed)`, no
    wrapper, BVH built before the clock starts: the reference that benchmarks divide by.
    query: 'INTERSECT' (closest hit, output=1 as RayTracer.closest_hit uses it) or 'OCCLUDED'."""
    if query not in ("INTERSECT", "OCCLUDED"):
        raise ConfigError(f"raw_embree_rate query is {query!r}, expected 'INTERSECT' or 'OCCLUDED'")
    if int(n_rays) < 1:
        raise ConfigError(f"raw_embree_rate n_rays is {n_rays}, expected >= 1")
    scene = _scene(*_check_mesh(vertices, faces))
    origins, dirs, far = aimed_rays(vertices, int(n_rays), seed)
    start = time.perf_counter()
    if query == "INTERSECT":
        scene.run(origins, dirs, dists=far, query="INTERSECT", output=1)
    else:
        scene.run(origins, dirs, dists=far, query="OCCLUDED")
    return n_rays / (time.perf_counter() - start)
