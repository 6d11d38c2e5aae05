"""Benchmark of the paper-size Method I problem (512 x 450 texels, 12 lights selected from 60).

Prints the time of every pipeline stage (and the parameters' uncertainty as a share of the fit's time) and the
rays/s of the two Embree stages (light selection over all candidates, shadow rays of the captured lights) over the
raw Embree occlusion rays/s measured in the same run on the same rays: one bare scene.run call on one
thread, and bare calls split over the same number of threads torchrefl uses. Speed is only
ever compared within one run (the machines are shared and noisy).

    python scripts/bench_local.py [--threads 2] [--out /tmp/bench_local]
    python scripts/bench_local.py --tiny      # the default scene at 32 x 24 texels, 4 lights (the test's mode)
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
from torchrefl.capture import load_scan_geometry, observation_geometry
from torchrefl.planning import select_for_scan
from torchrefl.synthetic import SyntheticScan

ROOT = Path(__file__).resolve().parents[1]
#: --tiny: the default scene shrunk to seconds
TINY = [
    "synthetic.columns=32",
    "synthetic.rows=24",
    "synthetic.angle_step_deg=11.25",
    "synthetic.height_step_mm=10.5",
    "synthetic.supersample=1",
    "synthetic.mesh_subdivisions=3",
    "selection.num_lights=4",
    "fit.iterations=3",
    "output.map_lights=0",
]


def shadow_rays(geom, heads, offset):
    """The occlusion rays observation_geometry traces for these lights: origins, unit dirs, far (float32)."""
    og = observation_geometry(geom, heads, shadow_offset=offset)
    x = geom.surface.positions.numpy().astype(np.float32)
    n = geom.surface.normals.numpy().astype(np.float32)
    origins = x + np.float32(offset) * n
    s = geom.texel_angles()
    u, w = (a.astype(np.float32) for a in geom.rig.head_axes(s))
    O, D, F = [], [], []
    for p, (lat, vert, rad) in enumerate(np.asarray(heads, dtype=np.float32)):
        light = rad * u + lat * w
        light[:, 1] += vert
        cand = np.flatnonzero(og["lit"][p] & og["seen"])
        seg = light[cand] - origins[cand]
        d = np.sqrt(np.einsum("ti,ti->t", seg, seg))
        O.append(origins[cand])
        D.append(seg / d[:, None])
        F.append(d - np.float32(offset))
    n_cam = int((og["cos_v"] > 0).sum())
    return np.concatenate(O), np.concatenate(D), np.concatenate(F), n_cam


def raw_rate(scene, O, D, F, threads: int) -> float:
    """Bare embreex occlusion rays/s on exactly these rays (one call per thread)."""
    parts = np.array_split(np.arange(len(O)), threads)
    start = time.perf_counter()
    if threads == 1:
        scene.run(O, D, dists=F.copy(), query="OCCLUDED")
    else:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(lambda idx: scene.run(O[idx], D[idx], dists=F[idx].copy(), query="OCCLUDED"), parts))
    return len(O) / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=None, help="output folder (default: a temporary folder)")
    ap.add_argument("--tiny", action="store_true", help="the default scene at 32 x 24 texels, 4 lights: seconds")
    args = ap.parse_args(argv)
    out = Path(args.out or tempfile.mkdtemp(prefix="bench_local_"))
    torch.set_num_threads(args.threads)
    cfg = torchrefl.load_config(
        ROOT / "configs" / "default.yaml",
        [f"output.dir={out / 'run'}", "selection.num_lights=12", "output.progress=false", f"threads={args.threads}"]
        + (TINY if args.tiny else []),
    )
    print(f"machine: {platform.processor() or platform.machine()}, threads {args.threads}, torch {torch.__version__}")

    metrics = torchrefl.fit(cfg, overwrite=True).metrics
    t = metrics["timing_s"]
    pipeline = ["light selection", "observations", "precompute", "initialise", "fit"]
    print(
        "\nstage times (s), paper-size problem: "
        f"{metrics['texels']} texels on a {cfg.synthetic.rows} x {cfg.synthetic.columns} grid, "
        f"{metrics['lights']} lights selected from {cfg.selection.grid.columns * cfg.selection.grid.rows}"
    )
    for k, v in t.items():
        mark = "  *" if k in pipeline else ""
        print(f"  {k:<18}{v:8.2f}{mark}")
    total = sum(t[k] for k in pipeline)
    print(f"  Method I pipeline (* = selection + shadow rays + precompute + initialise + fit): {total:.2f} s")
    share = t.get("uncertainty", 0.0) / t["fit"]
    print(
        f"  uncertainty (torchrefl.fit.uncertainty): {t.get('uncertainty', 0.0):.2f} s, {share:.1%} of the fit's time"
    )

    # Embree stages against raw Embree on the same rays, same run
    geom = load_scan_geometry(out / "run" / "capture", threads=args.threads)
    scan = SyntheticScan(cfg.synthetic, cfg.selection.grid, seed=cfg.seed)
    candidates = scan.candidate_positions()
    chosen = np.array(json.loads((out / "run" / "selection" / "selection.json").read_text())["chosen"])
    rows = []
    for name, heads in (
        ("light selection (60 candidates)", candidates),
        ("shadow rays (12 lights)", candidates[chosen]),
    ):
        O, D, F, n_cam = shadow_rays(geom, heads, cfg.geometry.shadow_offset_mm)
        start = time.perf_counter()
        if name.startswith("light"):
            select_for_scan(geom, heads, cfg.selection, cfg.reflectance, cfg.geometry.shadow_offset_mm)
        else:
            observation_geometry(geom, heads, shadow_offset=cfg.geometry.shadow_offset_mm)
        ours_s = time.perf_counter() - start
        n_rays = len(O) + n_cam
        ours = n_rays / ours_s
        raw1 = raw_rate(geom.tracer.scene, O, D, F, 1)
        rawN = raw_rate(geom.tracer.scene, O, D, F, args.threads)
        rows.append((name, n_rays, ours_s, ours, raw1, rawN))
    print("\nEmbree stages (whole stage incl. ray generation and BRDF geometry, vs bare scene.run on the same rays):")
    print(
        f"  {'stage':<34}{'rays':>11}{'time s':>9}{'ours M/s':>10}{'raw 1t M/s':>12}"
        f"{'raw ' + str(args.threads) + 't M/s':>12}{'ours/raw1t':>12}{'ours/raw' + str(args.threads) + 't':>11}"
    )
    for name, n, s, ours, r1, rN in rows:
        print(
            f"  {name:<34}{n:>11}{s:>9.2f}{ours / 1e6:>10.2f}{r1 / 1e6:>12.2f}{rN / 1e6:>12.2f}"
            f"{ours / r1:>12.2f}{ours / rN:>11.2f}"
        )
    gt = metrics.get("ground_truth", {})
    print(
        f"\naccuracy: pd_rmse {gt.get('pd_rmse'):.4f}, ps_median_rel_err {gt.get('ps_median_rel_err'):.4f}, "
        f"sigma_median_rel_err {gt.get('sigma_median_rel_err'):.4f}, rerender mean_abs_diff_8bit "
        f"{metrics['rerender']['mean_abs_diff_8bit']:.3f}"
    )
    (out / "bench_local.json").write_text(
        json.dumps(
            {
                "timing_s": t,
                "pipeline_s": total,
                "uncertainty_share_of_fit": share,
                "embree": [
                    dict(
                        zip(
                            (
                                "stage",
                                "rays",
                                "time_s",
                                "ours_rays_per_s",
                                "raw_1thread_rays_per_s",
                                "raw_nthreads_rays_per_s",
                            ),
                            r,
                        )
                    )
                    for r in rows
                ],
                "ground_truth": gt,
            },
            indent=2,
        )
    )
    print(f"\nwritten {out / 'bench_local.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
