"""Benchmark of the Embree boundary (torchrefl.core.rays) against bare embreex, measured in the same run.

Builds a displaced sphere of about 100k triangles, fires the same random rays aimed at it
(rays.aimed_rays) through
  - one bare single-threaded scene.run call (raw_embree_rate's reference; BVH built beforehand),
  - bare scene.run split over two threads (what the threads can give at best),
  - RayTracer.closest_hit / RayTracer.occluded with threads=1 and threads=2, float64 input
    (validation, float32 conversion, normalisation and output packing included),
and prints rays/s and ours/raw ratios. Each figure is the best of --repeat runs (the machines are
shared and noisy); only ratios from one run are meaningful.

    python scripts/bench_rays.py [--rays 2000000] [--repeat 3] [--count 158]
    python scripts/bench_rays.py --tiny      # 20 000 rays on a 16 x 16 sphere, once (the test's mode)
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import trimesh

from torchrefl.core import RayTracer, aimed_rays


def displaced_sphere(count: int) -> trimesh.Trimesh:
    """UV sphere (about 2 * count^2 triangles) with a radial bump pattern, so rays can hit it twice."""
    m = trimesh.creation.uv_sphere(radius=1.0, count=[count, count])
    v = m.vertices
    theta = np.arctan2(v[:, 1], v[:, 0])
    phi = np.arccos(np.clip(v[:, 2], -1, 1))
    r = 1.0 + 0.15 * np.sin(6 * theta) * np.sin(5 * phi) ** 2
    return trimesh.Trimesh(v * r[:, None], m.faces, process=False)


def best_rate(fn, n: int, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return n / best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rays", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--count", type=int, default=158, help="uv sphere resolution (158: ~100k triangles)")
    ap.add_argument("--tiny", action="store_true", help="20 000 rays, a 16 x 16 sphere, once: seconds")
    args = ap.parse_args(argv)
    if args.tiny:
        args.rays, args.repeat, args.count = 20_000, 1, 16

    mesh = displaced_sphere(args.count)
    start = time.perf_counter()
    tracers = {t: RayTracer(mesh.vertices, mesh.faces, threads=t) for t in (1, 2)}
    build = (time.perf_counter() - start) / 2
    scene = tracers[1].scene
    o32, d32, far32 = aimed_rays(mesh.vertices, args.rays, seed=0)
    o64, d64, far64 = o32.astype(np.float64), d32.astype(np.float64), far32.astype(np.float64)
    n = args.rays
    hit_frac = float(tracers[1].closest_hit(o32[:100_000], d32[:100_000], far32[:100_000]).hit.mean())

    def raw(query: str, threads: int):
        kw = {"output": 1} if query == "INTERSECT" else {}
        parts = np.array_split(np.arange(n), threads) if threads > 1 else None

        def go():
            if parts is None:
                scene.run(o32, d32, dists=far32.copy(), query=query, **kw)
            else:
                with ThreadPoolExecutor(threads) as pool:
                    list(pool.map(lambda i: scene.run(o32[i], d32[i], dists=far32[i], query=query, **kw), parts))

        return go

    rows = []
    for label, query, method in (("closest hit", "INTERSECT", "closest_hit"), ("occlusion", "OCCLUDED", "occluded")):
        raw1 = best_rate(raw(query, 1), n, args.repeat)
        raw2 = best_rate(raw(query, 2), n, args.repeat)
        ours = {t: best_rate(lambda: getattr(tracers[t], method)(o64, d64, far64), n, args.repeat) for t in (1, 2)}
        rows.append((label, raw1, raw2, ours[1], ours[2]))

    print(
        f"mesh: displaced uv sphere, {len(mesh.faces)} triangles (BVH build {build * 1e3:.0f} ms); "
        f"{n} rays, {hit_frac:.0%} hit; best of {args.repeat}; {platform.processor() or platform.machine()}"
    )
    head = [
        "query",
        "raw 1t M/s",
        "raw 2t M/s",
        "ours 1t M/s",
        "ours 2t M/s",
        "ours1t/raw1t",
        "ours2t/raw1t",
        "ours2t/raw2t",
    ]
    print("  ".join(f"{h:>12}" for h in head))
    for label, r1, r2, o1, o2 in rows:
        vals = [r1 / 1e6, r2 / 1e6, o1 / 1e6, o2 / 1e6, o1 / r1, o2 / r1, o2 / r2]
        print(f"{label:>12}  " + "  ".join(f"{v:>12.2f}" for v in vals))
    return 0


if __name__ == "__main__":
    sys.exit(main())
