"""Benchmark of the photon level (Method III) on the paper-size problem: 512 x 450 texels, 12 lights,
2 million photons per light and cache refresh.

1. End to end: Object E (glossy paper) is scanned and its 12 textures rendered with direct light
   only (the capture's content does not change the photon level's cost; path tracing the textures
   would add minutes of scene simulation), then `fit.model: photon` runs; the time of the
   precompute, initialise and fit stages is the photon level's end-to-end time.
2. Embree efficiency, in the same run: photon tracing and form-factor rays/s (rays traced / wall
   time of the whole stage, sampling and bookkeeping included; for the photons both the tracing alone
   and the whole refresh, tracing + reduction to the cache) over bare embreex closest-hit rays/s on the
   same number of threads, (a) on exactly the rays the photon tracer sent to Embree, replayed (the
   strict reference: same rays, nothing around them) and (b) on rays aimed at the same mesh from
   outside (coherent and cheaper per ray than bounce rays that start on the surface).
3. Scaling: the time of one cache refresh against photons per light, lights and texels.

    python scripts/bench_photon.py [--threads 2] [--photons 2000000] [--outer 3] [--specular-smoothing 0]
        [--smoothing 1] [--no-scaling] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

import torchrefl
from torchrefl.capture import Capture, load_scan_geometry
from torchrefl.core import RayTracer, Stages, aimed_rays
from torchrefl.fit import level_inputs
from torchrefl.synthetic import synthetic_capture
from torchrefl.transport import PhotonLevel, RadiosityLevel, form_factors_for_surface

ROOT = Path(__file__).resolve().parents[1]


def bare_intersect_rate(vertices, faces, n_rays: int, threads: int) -> float:
    """Bare embreex closest-hit rays/s on rays aimed at the mesh, split over `threads` calls."""
    scene = RayTracer(vertices, faces, threads=1).scene
    o, d, far = aimed_rays(vertices, n_rays, seed=1)
    parts = np.array_split(np.arange(n_rays), threads)
    start = time.perf_counter()
    if threads == 1:
        scene.run(o, d, dists=far.copy(), query="INTERSECT", output=1)
    else:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda i: scene.run(o[i], d[i], dists=far[i].copy(), query="INTERSECT", output=1), parts))
    return n_rays / (time.perf_counter() - start)


def bare_replay_rate(tracer, record: list, threads: int) -> float:
    """Bare embreex closest-hit rays/s on exactly the rays a photon trace sent to Embree (`record`: its
    (origins, directions) batches), the batches split over `threads` threads: the same work as the trace's
    Embree calls with everything around them removed."""
    far = [np.full(len(o), 1e37, np.float32) for o, _ in record]
    run = lambda i: tracer.scene.run(record[i][0], record[i][1], dists=far[i], query="INTERSECT", output=1)
    start = time.perf_counter()
    if threads == 1:
        for i in range(len(record)):
            run(i)
    else:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(run, range(len(record))))
    return sum(len(o) for o, _ in record) / (time.perf_counter() - start)


def overrides(out: Path, args, columns=512, rows=450, angle=0.7, height=0.56, lights=12) -> list[str]:
    return [
        f"output.dir={out}",
        "output.progress=false",
        "output.map_lights=0",
        f"threads={args.threads}",
        "synthetic.indirect_samples=0",
        "synthetic.supersample=1",
        f"synthetic.columns={columns}",
        f"synthetic.rows={rows}",
        f"synthetic.angle_step_deg={angle}",
        f"synthetic.height_step_mm={height}",
        f"selection.num_lights={lights}",
        "fit.model=photon",
        f"photon.photons_per_light={args.photons}",
        f"photon.outer_iterations={args.outer}",
        f"photon.specular_smoothing={args.specular_smoothing}",
        f"photon.smoothing={args.smoothing}",
        # the library defaults where the glossy Object E config departs from them (the bench times the defaults)
        "photon.diffuse_paths=photons",
        "photon.specular_gather=0",
        "radiosity.hemisphere_samples=256",
        "geometry.median_size=5",
        "geometry.crease_angle_deg=null",
    ]


def refresh_time(
    cfg, out: Path, photons: int, lights: int | None = None, record: list | None = None
) -> tuple[float, dict]:
    """Seconds of one cache refresh (photon tracing + cache reduction) with fixed parameters (Object E's truth);
    with `record`, the rays of a second, identical refresh are appended to it."""
    quiet = lambda *a: None
    cap, _ = synthetic_capture(cfg, out, Stages(quiet), quiet)
    surface, obs = cap.surface, cap.obs
    if lights is not None:
        obs = obs.subset_lights(list(range(lights)))
    inputs = level_inputs(cfg, Capture(surface, obs), quiet)[0]
    photon = PhotonLevel(inputs, RadiosityLevel(inputs))  # every path from photons: the radiosity level unused
    photon.prepare()
    level = photon.refresher
    level.photons_per_light = photons
    T = surface.num_texels
    pd = torch.full((T, 3), 0.55)
    ps = torch.full((T, 3), 0.35)
    sigma = torch.full((T,), 0.08)
    level.cache(pd, ps, sigma, refresh=0)  # landing densities (shadow rays), BVH warm-up
    start = time.perf_counter()
    cache = level.cache(pd, ps, sigma, refresh=1)
    seconds = time.perf_counter() - start
    stats = {"texels": T, "lights": obs.num_lights, **cache.stats}
    if record is not None:  # the rays of one more identical refresh, for the replay
        rt = level.tracer.tracer
        plain = rt.first_hits
        rt.first_hits = lambda o, d: (record.append((o, d)), plain(o, d))[1]
        level.cache(pd, ps, sigma, refresh=1)
        rt.first_hits = plain
        stats["tracer"] = rt
    return seconds, stats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--photons", type=int, default=2_000_000, help="photons per light and refresh")
    ap.add_argument(
        "--outer", type=int, default=3, help="photon.outer_iterations of the end-to-end run (3: the library default)"
    )
    ap.add_argument(
        "--specular-smoothing",
        type=float,
        default=0.0,
        help="photon.specular_smoothing (0: the library default; the glossy Object E config uses 1.0, "
        "~2.5x the fit time)",
    )
    ap.add_argument(
        "--smoothing",
        type=float,
        default=1.0,
        help="photon.smoothing (1: the library default; the Object E configs use 2.0 at this size)",
    )
    ap.add_argument("--no-scaling", action="store_true")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_photon_"))
    torch.set_num_threads(args.threads)
    config = ROOT / "configs" / "object_e_setup2.yaml"
    report: dict = {
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, {args.threads} Embree threads",
        "photons_per_light": args.photons,
        "outer_iterations": args.outer,
        "specular_smoothing": args.specular_smoothing,
        "smoothing": args.smoothing,
    }

    # 1. end to end
    cfg = torchrefl.load_config(config, overrides(out / "e2e", args))
    metrics = torchrefl.fit(cfg, overwrite=True).metrics
    t = metrics["timing_s"]
    report["end_to_end_s"] = round(sum(t.get(k, 0.0) for k in ("precompute", "initialise", "fit")), 2)
    report["stages_s"] = t
    report["photon"] = metrics.get("photon")

    # 2. rays/s against bare Embree, same run
    capture = out / "e2e" / "capture"
    base = torchrefl.load_config(
        config, overrides(out / "rate", args) + ["capture.kind=cylindrical_scan", f"capture.path={capture}"]
    )
    record: list = []
    seconds, stats = refresh_time(base, out / "rate", args.photons, record=record)
    tracer_of_run = stats.pop("tracer")
    replay = bare_replay_rate(tracer_of_run, record, args.threads)
    del record
    ours = stats["rays"] / seconds
    tracing = stats["rays"] / stats["trace_s"]

    geom = load_scan_geometry(capture)
    V, F = geom.surface.mesh_vertices, geom.surface.mesh_faces
    bare1 = bare_intersect_rate(V, F, 2_000_000, 1)
    bareN = bare_intersect_rate(V, F, 2_000_000, args.threads)
    report["photon_tracing"] = {
        "refresh_s": round(seconds, 2),
        "trace_s": stats["trace_s"],
        "reduce_s": stats["reduce_s"],
        "rays": stats["rays"],
        "tracing_rays_per_s": round(tracing),
        "refresh_rays_per_s": round(ours),
        f"bare_replay_rays_per_s_{args.threads}_threads": round(replay),
        "bare_aimed_rays_per_s_1_thread": round(bare1),
        f"bare_aimed_rays_per_s_{args.threads}_threads": round(bareN),
        "tracing_ratio_to_bare_replay": round(tracing / replay, 3),
        "refresh_ratio_to_bare_replay": round(ours / replay, 3),
        "tracing_ratio_to_bare_aimed": round(tracing / bareN, 3),
        "refresh_ratio_to_bare_aimed": round(ours / bareN, 3),
        "stats": stats,
    }

    tracer = RayTracer(V, F, threads=args.threads)
    rc = base.radiosity  # the configured (default) patch size and hemisphere samples
    start = time.perf_counter()
    patches, Fm = form_factors_for_surface(
        geom.surface,
        tracer,
        patch_size=rc.patch_size,
        samples_per_patch=rc.hemisphere_samples,
        split_angle_deg=rc.patch_split_angle_deg,
    )
    ff_s = time.perf_counter() - start
    ff_rays = patches.num_patches * rc.hemisphere_samples
    report["form_factors"] = {
        "patches": patches.num_patches,
        "patch_size": rc.patch_size,
        "samples_per_patch": rc.hemisphere_samples,
        "rays": ff_rays,
        "seconds": round(ff_s, 2),
        "rays_per_s": round(ff_rays / ff_s),
        "ratio_to_bare_same_threads": round(ff_rays / ff_s / bareN, 3),
    }

    # 3. scaling of one refresh
    if not args.no_scaling:
        rows = []
        for photons in (args.photons // 4, args.photons // 2, args.photons):
            s, st = refresh_time(base, out / "scale", photons)
            rows.append(
                {
                    "vary": "photons",
                    "photons_per_light": photons,
                    "lights": st["lights"],
                    "texels": st["texels"],
                    "seconds": round(s, 2),
                }
            )
        for lights in (3, 6):
            s, st = refresh_time(base, out / "scale", args.photons, lights=lights)
            rows.append(
                {
                    "vary": "lights",
                    "photons_per_light": args.photons,
                    "lights": lights,
                    "texels": st["texels"],
                    "seconds": round(s, 2),
                }
            )
        for cols, rws, ang, hgt in ((128, 112, 2.8, 2.24), (256, 225, 1.4, 1.12)):
            small = torchrefl.load_config(config, overrides(out / f"tex{cols}", args, cols, rws, ang, hgt))
            s, st = refresh_time(small, out / f"tex{cols}", args.photons)
            rows.append(
                {
                    "vary": "texels",
                    "photons_per_light": args.photons,
                    "lights": st["lights"],
                    "texels": st["texels"],
                    "seconds": round(s, 2),
                }
            )
        report["scaling"] = rows
    (out / "bench_photon.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    print(f"\nwritten {out / 'bench_photon.json'}")


if __name__ == "__main__":
    main()
