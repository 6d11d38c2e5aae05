"""Benchmark of the photon level (Method III) in its real glossy configuration: the non-uniform glossy fold
(configs/fold.yaml: 34 449 texels, 20 lights, textures path traced with interreflection) fitted with
`fit.model=photon` and the config's own settings (photon and radiosity defaults, specular gather, LM refits).

1. End to end: the fit's wall and CPU seconds (precompute + initialise + fit), its peak resident memory, the image
   difference after every photon refresh with the seconds into the fit at which it was reached, and the accuracy
   against docs/results/fold.md's targets (pd_rmse <= 0.01, held-out mean |diff| <= 0.5 DN, Ps / sigma median
   relative errors <= 0.05): the time to reach the targets is the fit's time when they all hold.
2. Embree efficiency, in the same run: photon tracing and form-factor rays/s (rays traced / wall time of the whole
   stage, sampling and bookkeeping included; for the photons both the tracing alone and the whole refresh, tracing +
   reduction to the cache + specular gather) over bare embreex closest-hit rays/s on the same number of threads,
   (a) on exactly the rays the photon tracer sent to Embree, replayed (the strict reference: same rays, nothing
   around them) and (b) on rays aimed at the same mesh from outside (coherent and cheaper per ray than bounce rays
   that start on the surface).
3. Scaling (--scaling): the time of one cache refresh against photons per light and lights.

    python scripts/bench_photon.py [--capture DIR] [--threads 2] [--set KEY=VALUE ...] [--scaling] [--out DIR]
    python scripts/bench_photon.py --tiny      # the tiny fold (scripts/tiny_mode.py): seconds, the test's mode

Rendering the fold's capture takes minutes; --capture fits an existing one (a run's capture/ folder) instead.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

import torchrefl
from torchrefl.capture.base import loader_for
from torchrefl.core import RayTracer, aimed_rays
from torchrefl.fit import level_inputs
from torchrefl.transport import form_factors_for_surface
from torchrefl.transport.levels.auto import named_level, prepare
from torchrefl.transport.levels.radiosity import SPLIT_ANGLE_DEG

sys.path.insert(0, str(Path(__file__).parent))
from tiny_mode import FOLD, TINY  # noqa: E402

#: docs/results/fold.md's accuracy targets (metrics.json key, largest value)
TARGETS = {
    ("ground_truth", "pd_rmse"): 0.01,
    ("holdout", "mean_abs_diff_8bit"): 0.5,
    ("ground_truth", "ps_median_rel_err"): 0.05,
    ("ground_truth", "sigma_median_rel_err"): 0.05,
}
FIT_STAGES = ("precompute", "initialise", "fit")


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


def refresh_time(cfg, capture: Path, photons: int | None = None, lights: int | None = None, record=None):
    """Seconds of one cache refresh (photon tracing + cache reduction + specular gather) of the configured level at
    fixed parameters (0.55 / 0.35 / 0.08 everywhere) and its stats; with `record`, the rays of a second, identical
    refresh are appended to it (and the RayTracer is stats['tracer'])."""
    quiet = lambda *a: None
    cap = loader_for("cylindrical_scan").load(capture, cfg, quiet)
    if lights is not None:
        cap.obs = cap.obs.subset_lights(list(range(lights)))
    inputs = level_inputs(cfg, cap, quiet)[0]
    level = named_level(inputs)
    prepare(level)
    refresher = level.refresher
    if photons is not None:
        refresher.photons_per_light = photons
    T = cap.surface.num_texels
    dtype = cap.obs.intensity.dtype
    pd, ps, sigma = torch.full((T, 3), 0.55, dtype=dtype), torch.full((T, 3), 0.35, dtype=dtype), torch.full((T,), 0.08)
    sigma = sigma.to(dtype)
    refresher.cache(pd, ps, sigma, refresh=0)  # landing densities (shadow rays), BVH warm-up
    start = time.perf_counter()
    cache = refresher.cache(pd, ps, sigma, refresh=1)
    seconds = time.perf_counter() - start
    stats = {"texels": T, "lights": cap.obs.num_lights, **cache.stats}
    if record is not None:  # the rays of one more identical refresh, for the replay
        rt = refresher.tracer.tracer
        plain = rt.first_hits
        rt.first_hits = lambda o, d: (record.append((o, d)), plain(o, d))[1]
        refresher.cache(pd, ps, sigma, refresh=1)
        rt.first_hits = plain
        stats["tracer"] = rt
    return seconds, stats


def end_to_end(cfg) -> dict:
    """Fit cfg; the fit's seconds, memory, image difference per refresh and accuracy against TARGETS."""
    cpu = time.process_time()
    m = torchrefl.fit(cfg, overwrite=True).metrics
    t, c = m["timing_s"], m.get("cpu_s", {})
    photon = m.get("photon") or {}
    accuracy = {key: (m.get(key[0]) or {}).get(key[1]) for key in TARGETS}
    met = all(v is not None and v <= TARGETS[k] for k, v in accuracy.items())
    fit_s = round(sum(t.get(k, 0.0) for k in FIT_STAGES), 2)
    return {
        "fit_wall_s": fit_s,
        "fit_cpu_s": round(sum(c.get(k, 0.0) for k in FIT_STAGES), 2),
        "run_cpu_s": round(time.process_time() - cpu, 2),
        "peak_memory_mb": m.get("peak_memory_mb"),
        "stages_s": t,
        "stages_cpu_s": c,
        "image_difference_per_refresh": photon.get("image_difference_per_refresh"),
        "refresh_at_s": photon.get("refresh_at_s"),
        "accuracy": {f"{a}.{b}": v for (a, b), v in accuracy.items()},
        "targets": {f"{a}.{b}": v for (a, b), v in TARGETS.items()},
        "seconds_to_targets": fit_s if met else None,
        "photon": photon,
    }


def embree_ratios(cfg, capture: Path, threads: int) -> dict:
    """Photon tracing, the whole refresh and the form factors against bare Embree rays/s, same mesh and threads."""
    record: list = []
    seconds, stats = refresh_time(cfg, capture, record=record)
    tracer_of_run = stats.pop("tracer")
    replay = bare_replay_rate(tracer_of_run, record, threads)
    del record
    ours, tracing = stats["rays"] / seconds, stats["rays"] / stats["trace_s"]
    surface = loader_for("cylindrical_scan").load(capture, cfg, lambda *a: None).surface
    V, F = surface.mesh_vertices, surface.mesh_faces
    n_aimed = max(200_000, min(2_000_000, stats["rays"]))
    bare1, bareN = bare_intersect_rate(V, F, n_aimed, 1), bare_intersect_rate(V, F, n_aimed, threads)
    tracer = RayTracer(V, F, threads=threads)
    rc = cfg.radiosity
    start = time.perf_counter()
    patches, _ = form_factors_for_surface(
        surface, tracer, patch_size=rc.patch_size, samples_per_patch=rc.hemisphere_samples,
        split_angle_deg=SPLIT_ANGLE_DEG,
    )  # fmt: skip
    ff_s = time.perf_counter() - start
    ff_rays = patches.num_patches * rc.hemisphere_samples
    return {
        "photon_tracing": {
            "refresh_s": round(seconds, 2),
            **{k: stats.get(k) for k in ("trace_s", "reduce_s", "gather_s", "rays", "photons_emitted")},
            "tracing_rays_per_s": round(tracing),
            "refresh_rays_per_s": round(ours),
            "bare_replay_rays_per_s": round(replay),
            "bare_aimed_rays_per_s_1_thread": round(bare1),
            "bare_aimed_rays_per_s": round(bareN),
            "tracing_ratio_to_bare_replay": round(tracing / replay, 3),
            "refresh_ratio_to_bare_replay": round(ours / replay, 3),
            "tracing_ratio_to_bare_aimed": round(tracing / bareN, 3),
            "refresh_ratio_to_bare_aimed": round(ours / bareN, 3),
        },
        "form_factors": {
            "patches": patches.num_patches,
            "samples_per_patch": rc.hemisphere_samples,
            "rays": ff_rays,
            "seconds": round(ff_s, 2),
            "rays_per_s": round(ff_rays / ff_s),
            "ratio_to_bare_aimed": round(ff_rays / ff_s / bareN, 3),
        },
    }


def scaling(cfg, capture: Path, photons: int) -> list[dict]:
    """One refresh's seconds at 1/4, 1/2 and all of `photons` per light, and at a quarter and half of the lights."""
    rows = []
    lights = loader_for("cylindrical_scan").load(capture, cfg, lambda *a: None).obs.num_lights
    for n, p in (
        (photons // 4, None),
        (photons // 2, None),
        (photons, None),
        (photons, lights // 4),
        (photons, lights // 2),
    ):
        s, st = refresh_time(cfg, capture, n, max(1, p) if p else None)
        rows.append({"photons_per_light": n, "lights": st["lights"], "texels": st["texels"], "seconds": round(s, 2)})
    return rows


def summary(report: dict) -> str:
    """The lines a reader wants first: time, memory, accuracy against the targets, the ratios to bare Embree."""
    e, pt, ff = report["end_to_end"], report["photon_tracing"], report["form_factors"]
    acc = ", ".join(
        f"{k.split('.')[1]} {v:.4g} (<= {e['targets'][k]:g})" for k, v in e["accuracy"].items() if v is not None
    )
    reached = "all targets met" if e["seconds_to_targets"] is not None else "targets not all met"
    diffs = e["image_difference_per_refresh"] or []
    at = e["refresh_at_s"] or [None] * len(diffs)
    per_refresh = "; ".join(f"{d:.3f} DN at {a:.1f} s" if a is not None else f"{d:.3f} DN" for d, a in zip(diffs, at))
    return "\n".join(
        [
            f"fit (precompute + initialise + fit): {e['fit_wall_s']:.1f} s wall, {e['fit_cpu_s']:.1f} s CPU; "
            f"peak resident memory {e['peak_memory_mb']} MiB",
            f"image difference per refresh: {per_refresh}",
            f"accuracy: {acc}; {reached}",
            f"photon tracing {pt['tracing_ratio_to_bare_replay']:.2f}, whole refresh "
            f"{pt['refresh_ratio_to_bare_replay']:.2f} of bare Embree on the same rays replayed "
            f"({pt['tracing_ratio_to_bare_aimed']:.2f} / {pt['refresh_ratio_to_bare_aimed']:.2f} of aimed rays); "
            f"form factors {ff['ratio_to_bare_aimed']:.2f} of aimed rays",
        ]
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--config", type=Path, default=FOLD, help="the glossy config timed (default configs/fold.yaml)")
    ap.add_argument("--capture", type=Path, default=None, help="fit this capture folder instead of rendering one")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", help="config overrides")
    ap.add_argument("--scaling", action="store_true", help="also one refresh against photons and lights")
    ap.add_argument("--tiny", action="store_true", help="the tiny fold: seconds (scripts/tiny_mode.py)")
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: a temporary one)")
    args = ap.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_photon_"))
    torch.set_num_threads(args.threads)
    over = (TINY if args.tiny else ["output.progress=false", "output.map_lights=0"]) + [f"threads={args.threads}"]
    over += ["fit.model=photon", *args.set]
    if args.capture is not None:
        over += ["capture.kind=cylindrical_scan", f"capture.path={args.capture.resolve()}"]
    cfg = torchrefl.load_config(args.config, over + [f"output.dir={out / 'e2e'}"])
    report: dict = {
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, {args.threads} Embree threads",
        "config": str(args.config.name),
        "overrides": args.set,
        "end_to_end": end_to_end(cfg),
    }
    capture = args.capture.resolve() if args.capture is not None else out / "e2e" / "capture"
    report.update(embree_ratios(cfg, capture, args.threads))
    if args.scaling:
        report["scaling"] = scaling(cfg, capture, cfg.photon.photons_per_light)
    (out / "bench_photon.json").write_text(json.dumps(report, indent=2))
    print(summary(report))
    print(f"written {out / 'bench_photon.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
