"""Time one relit frame (torchrefl.report.relight): the whole frame and, in the same run, the bare Embree closest
hits of its primary rays (the floor no renderer on this mesh goes below).

    python scripts/bench_render.py RUN_DIR [--size 512] [--repeats 5] [--threads 2]
    python scripts/bench_render.py --tiny        # a 24 x 24 texel cap, one 64 x 64 frame (the test's mode)
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from torchrefl.report.relight import Light, default_intensity
from torchrefl.report.relight_camera import camera_rays, orbit_camera
from torchrefl.report.run_marker import write_marker
from torchrefl.report.run_result import load_run


def tiny_run(folder: Path) -> Path:
    """A run folder on a spherical cap of radius 50 mm (24 x 24 texels)."""
    u, v = np.meshgrid(np.linspace(-0.6, 0.6, 24), np.linspace(-0.6, 0.6, 24))
    n = np.stack([u, -v, np.sqrt(1.0 - u * u - v * v)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    ones = np.ones((24, 24))
    np.savez(folder / "params.npz", pd=0.5 * ones[..., None].repeat(3, -1), ps=0.2 * ones[..., None],
             sigma=0.2 * ones, mask=ones > 0, brdf=np.array("torrance_sparrow"), positions=50 * n, normals=n,
             kappa=np.full(3, np.pi), units=np.array("mm"))  # fmt: skip
    (folder / "metrics.json").write_text(
        '{"model": "local", "brdf": "torrance_sparrow", "texels": 576, "lights": 1, "timing_s": {"total": 1}, '
        '"rerender": {}}'
    )
    (folder / "config.yaml").write_text("{}\n")
    write_marker(folder)
    return folder


def bench(folder, size: int, repeats: int) -> dict:
    """Median seconds of a size x size frame (orbit 30 20, a point light orbit 60 35, 1 ray per pixel, shadows),
    of the scene's build, and of the bare closest hits of its primary rays."""
    run = load_run(folder)
    t0 = time.perf_counter()
    scene = run.scene
    build = time.perf_counter() - t0
    cam = orbit_camera(scene.centre, scene.radius, 30, 20, 4 * scene.radius, size, size)
    where = scene.centre + 4 * scene.radius * np.array([0.5, 0.6, 0.6])
    light = Light(default_intensity(run, scene, where), position=where)
    frames, hits = [], []
    o, d, _ = camera_rays(cam)
    for _ in range(repeats):
        t0 = time.perf_counter()
        run.render(camera=cam, light=light)
        frames.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        scene.tracer.closest_hit(o, d)
        hits.append(time.perf_counter() - t0)
    return {"frame_s": statistics.median(frames), "primary_hits_s": statistics.median(hits), "scene_s": build}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", nargs="?", help="a run folder")
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--threads", type=int, default=2, help="torch threads (Embree uses the scene's 2)")
    p.add_argument("--tiny", action="store_true", help="a tiny run and one 64 x 64 frame")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        folder = tiny_run(Path(tmp)) if args.tiny else args.run
        size, repeats = (64, 1) if args.tiny else (args.size, args.repeats)
        r = bench(folder, size, repeats)
    print(
        f"{size} x {size} frame: {r['frame_s']:.3f} s (median of {repeats}); its primary rays' closest hits alone "
        f"{r['primary_hits_s']:.3f} s ({r['primary_hits_s'] / r['frame_s']:.0%} of the frame); scene built in "
        f"{r['scene_s']:.3f} s; torch threads {args.threads}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
