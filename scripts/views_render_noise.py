"""The synthetic mesh_views renderer's Monte Carlo noise per pixel on the concave bowl, and its CPU cost.

Renders a random sample of camera 0's covered pixels (under the lights paired with it) twice, with seeds 0 and 1,
and prints the mean interreflected light and the noise per pixel (the RMS of the two renders' difference over
sqrt 2), in 8-bit digital numbers, with the CPU time of one render. --max-bounces 1 keeps the first bounce only
(the light reflected once inside the object before the observed point); --min-bounces sets where Russian roulette
starts. Results: docs/results/mesh_views.md (the concave bowl).

    python scripts/views_render_noise.py --paths 64
    python scripts/views_render_noise.py --tiny      # 2 paths, 40 pixels (the test's mode)
"""

from __future__ import annotations

import argparse
import sys
import time
from functools import partialmethod

import numpy as np

import torchrefl.synthetic.path_tracer as path_tracer
from torchrefl.config import MeshViewsConfig
from torchrefl.synthetic.mesh_views import build_scene
from torchrefl.synthetic.views_render import ViewsRenderer


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=64, help="interreflection paths per sub-pixel ray")
    ap.add_argument("--pixels", type=int, default=6000, help="covered pixels sampled from camera 0")
    ap.add_argument("--max-bounces", type=int, default=32)
    ap.add_argument("--min-bounces", type=int, default=2)
    ap.add_argument("--tiny", action="store_true", help="2 paths, 40 pixels, 4 bounces: seconds")
    a = ap.parse_args(argv)
    if a.tiny:
        a.paths, a.pixels, a.max_bounces = 2, 40, 4
    plain_init = path_tracer.IndirectRenderer.__init__
    path_tracer.IndirectRenderer.__init__ = partialmethod(
        path_tracer.IndirectRenderer.__init__, min_bounces=min(a.min_bounces, a.max_bounces), max_bounces=a.max_bounces
    )
    scene = build_scene(MeshViewsConfig(object="bowl"), 0)
    cam = scene.cameras[0]
    by_name = {light.name: light for light in scene.lights}
    lights = [by_name[im.light] for im in scene.images if im.camera == cam.name]
    direct = ViewsRenderer(scene.object)
    covered = np.flatnonzero(direct.radiance(cam, lights).covered)
    pix = np.sort(np.random.default_rng(5).choice(covered, min(a.pixels, len(covered)), replace=False))
    runs, cpu = [], []
    for seed in (0, 1):
        start = time.process_time()
        r = ViewsRenderer(scene.object, indirect_samples=a.paths, seed=seed)
        runs.append(r.radiance(cam, lights, camera_index=0, pixels=pix).values * 255)
        cpu.append(time.process_time() - start)
    indirect = (runs[0] + runs[1]) / 2 - direct.radiance(cam, lights, pixels=pix).values * 255
    noise = np.sqrt(np.mean((runs[0] - runs[1]) ** 2) / 2)
    t = float(np.mean(cpu))
    print(
        f"{a.paths} paths, bounces {a.min_bounces}..{a.max_bounces}, {len(pix)} px x {len(lights)} lights: "
        f"CPU {t:.1f} s per render; interreflected light {indirect.mean():.2f} DN; noise {noise:.3f} DN per pixel; "
        f"noise x sqrt(CPU s) {noise * np.sqrt(t):.3f}"
    )
    path_tracer.IndirectRenderer.__init__ = plain_init
    return 0


if __name__ == "__main__":
    sys.exit(main())
