"""mesh_views at scale (issue 32 item 7): time and peak memory of the loader and a local (Method I) fit on a large
atlas seen by many 2-megapixel images, and the camera-visibility rays against raw Embree in the same run.

The capture is the synthetic convex ellipsoid (torchrefl.synthetic.mesh_views, direct light only) photographed by
12 cameras on three rings under 6 point lights, written once into a folder (default: under the system's temporary
folder, named after the case) and reused by later runs. Sizes (--case):

    full      1024^2 atlas (~1.03 M texels), 48 images of 1632 x 1224 px (2.0 MP): 4 lights per camera
    quarter   512^2 atlas (~258 k texels), 12 images of 1632 x 1224 px: 1 light per camera
    tiny      32^2 atlas, 12 images of 96 x 72 px (seconds: tests/scripts/test_bench_mesh_views_scale.py)

The focal length makes one texel about 3.5 px across at the object's near side (the loader leaves texels narrower
than 2.5 px out of an image), so at full size each camera sees a part of the object and most texels are seen by a
few images. Stages: render (only when the folder is new), load: geometry (mesh + atlas), load: observations
(load_views_observations), load: other (the rest of MeshViewsLoader.load: the folder's metadata, the BVH, the truth,
the texel mesh), then the fit's own stages (fit: precompute, initialise, fit). Each stage's peak resident memory is
the kernel's VmHWM reset at the stage's start (/proc/self/clear_refs; torchrefl.core.memory), the run's
peak the largest of them. The rays part replays the rays camera_view casts (texel visibility and depth steps)
through the bare embreex scene (float32 contiguous, split over the same threads) and compares rays per second.

    python scripts/bench_mesh_views_scale.py --case quarter [--folder DIR] [--markdown results.md]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

import torchrefl.capture.mesh_views as mesh_views
from torchrefl.capture.mesh_views import MeshViewsLoader
from torchrefl.config import MeshViewsConfig, load_config
from torchrefl.core.memory import peak_resident_mb, reset_peak
from torchrefl.core.progress import Stages
from torchrefl.core.rays import RayTracer
from torchrefl.fit.pipeline import fit_capture
from torchrefl.report.metrics import ground_truth_errors
from torchrefl.synthetic.mesh_views import write_capture

LIGHTS_DEG = [[30.0, 20.0], [150.0, -10.0], [270.0, 40.0], [90.0, -30.0], [210.0, 45.0], [330.0, -20.0]]


@dataclass(frozen=True)
class Case:
    """One capture size: atlas side (texels), image size (px), focal length (px), lights per camera (of 6)."""

    name: str
    texture_size: int
    width: int
    height: int
    focal_px: float
    lights_per_view: int

    @property
    def images(self) -> int:
        return 12 * self.lights_per_view

    def views(self) -> MeshViewsConfig:
        """The config's `views` section of this capture (3 rings of 4 cameras, 6 lights, no supersampling)."""
        return MeshViewsConfig(
            object="ellipsoid",
            width=self.width,
            height=self.height,
            focal_px=self.focal_px,
            camera_elevations_deg=[-35.0, 5.0, 40.0],
            cameras_per_ring=4,
            lights_deg=LIGHTS_DEG,
            lights_per_view=self.lights_per_view,
            supersample=1,
        )


CASES = {
    "full": Case("full", 1024, 1632, 1224, 6400.0, 4),
    "quarter": Case("quarter", 512, 1632, 1224, 3200.0, 1),
    "tiny": Case("tiny", 32, 96, 72, 220.0, 1),
}


@dataclass
class Segment:
    """One measured stage: wall seconds, the process's CPU seconds and the peak resident memory during it (bytes)."""

    name: str
    seconds: float
    peak_bytes: int
    cpu_seconds: float = 0.0


@dataclass
class Meter:
    """Flat stages in order: `mark(name)` closes the stage that is open and opens `name`."""

    segments: list[Segment] = field(default_factory=list)
    resets: bool = True
    _open: str | None = None
    _start: float = 0.0
    _cpu: float = 0.0

    def mark(self, name: str | None) -> None:
        now, cpu = time.perf_counter(), time.process_time()
        if self._open is not None:
            peak = int(peak_resident_mb() * 2**20)
            self.segments.append(Segment(self._open, now - self._start, peak, cpu - self._cpu))
        self.resets = reset_peak() and self.resets
        self._open, self._start, self._cpu = name, time.perf_counter(), time.process_time()

    @contextmanager
    def stage(self, name: str, after: str | None = None):
        self.mark(name)
        try:
            yield
        finally:
            self.mark(after)


class MeteredStages(Stages):
    """The fit's Stages, each also a Meter stage (what runs between them: 'fit: other')."""

    def __init__(self, meter: Meter, log):
        super().__init__(log)
        self.meter = meter

    @contextmanager
    def stage(self, name: str):
        with self.meter.stage(f"fit: {name}", "fit: other"), super().stage(name):
            yield


@contextmanager
def metered(meter: Meter, module, name: str, label: str, after: str):
    """Replace module.name (a function) by one that runs as Meter stage `label` while the block runs."""
    inner = getattr(module, name)

    def wrapped(*args, **kwargs):
        with meter.stage(label, after):
            return inner(*args, **kwargs)

    setattr(module, name, wrapped)
    try:
        yield
    finally:
        setattr(module, name, inner)


def render(case: Case, folder: Path, threads: int) -> bool:
    """Write the capture into folder unless images.json (written last) is there; True when it rendered."""
    if (folder / "images.json").is_file():
        return False
    write_capture(folder, case.views(), texture_size=case.texture_size, seed=0, threads=threads)
    return True


def config(case: Case, folder: Path, threads: int):
    """configs/mesh_views.yaml reading the folder as a capture on disk, at the case's atlas, no held-out image."""
    return load_config(
        "mesh_views",
        [
            "capture.kind=mesh_views",
            f"capture.path={folder}",
            f"capture.texture_size={case.texture_size}",
            "fit.holdout=[]",
            f"threads={threads}",
            "output.progress=false",
        ],
    )


# ---------------------------------------------------------------------------- camera-visibility rays


class RecordingTracer:
    """A RayTracer whose closest_hit calls are timed and their rays kept (float32 unit directions) for replay."""

    def __init__(self, tracer: RayTracer):
        self.tracer = tracer
        self.seconds = 0.0
        self.rays: list[tuple[np.ndarray, np.ndarray]] = []

    def closest_hit(self, origins, directions, *args, **kwargs):
        start = time.perf_counter()
        hits = self.tracer.closest_hit(origins, directions, *args, **kwargs)
        self.seconds += time.perf_counter() - start
        d = np.ascontiguousarray(directions, dtype=np.float32)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        self.rays.append((np.ascontiguousarray(origins, dtype=np.float32), d))
        return hits


@dataclass
class RayRates:
    """Camera-visibility rays per second: camera_view's closest_hit calls (ours), the whole camera_view call
    (projection and footprints included), and the same rays through the bare embreex scene on 1 and on `threads`
    threads."""

    rays: int
    threads: int
    ours: float
    camera_view: float
    raw_1t: float
    raw_nt: float


def _raw_seconds(scene, rays: list, threads: int) -> float:
    """Seconds of bare scene.run INTERSECT calls (output=1) on the recorded rays, each batch split over threads."""
    start = time.perf_counter()
    for o, d in rays:
        parts = np.array_split(np.arange(len(o)), threads)

        def go(i, o=o, d=d):
            oo, dd = o[i[0] : i[-1] + 1], d[i[0] : i[-1] + 1]
            scene.run(oo, dd, dists=np.full(len(oo), 1e37, np.float32), query="INTERSECT", output=1)

        if threads == 1:
            go(parts[0])
        else:
            with ThreadPoolExecutor(threads) as pool:
                list(pool.map(go, [p for p in parts if len(p)]))
    return time.perf_counter() - start


def ray_rates(meta, geom, tracer: RayTracer, cfg, repeat: int = 2) -> RayRates:
    """RayRates over every camera of the capture, best of `repeat` for each figure."""
    frame = mesh_views.texel_frame(geom)
    best = {"ours": np.inf, "view": np.inf, "raw1": np.inf, "rawn": np.inf}
    rays: list = []
    for _ in range(repeat):
        rec = RecordingTracer(tracer)
        start = time.perf_counter()
        for cam in range(len(meta.cameras)):
            mesh_views.frame_view(meta, cam, frame, rec, cfg)
        best["view"] = min(best["view"], time.perf_counter() - start)
        best["ours"] = min(best["ours"], rec.seconds)
        rays = rec.rays
    for _ in range(repeat):
        best["raw1"] = min(best["raw1"], _raw_seconds(tracer.scene, rays, 1))
        best["rawn"] = min(best["rawn"], _raw_seconds(tracer.scene, rays, tracer.threads))
    n = sum(len(o) for o, _ in rays)
    return RayRates(n, tracer.threads, n / best["ours"], n / best["view"], n / best["raw1"], n / best["rawn"])


# ---------------------------------------------------------------------------- the run


@dataclass
class ScaleResult:
    """What one run measured."""

    case: Case
    texels: int
    images: int
    valid_observations: int
    texels_seen: int
    segments: list[Segment]
    peak_bytes: int
    resets: bool
    rays: RayRates | None
    errors: dict | None  # report.metrics.ground_truth_errors against truth.npz


def measure(case: Case, folder: Path, threads: int = 2, rays: bool = True, fit: bool = True, log=None) -> ScaleResult:
    """Render (when needed), load and (fit: True) fit the case's capture in this process, stage by stage (module
    doc), then the camera-visibility rays."""
    log = log or (lambda msg, echo=True: None)
    torch.set_num_threads(threads)
    meter = Meter()
    meter.mark("render (a new folder only)")
    rendered = render(case, folder, threads)
    meter.mark(None)
    if not rendered:
        meter.segments.clear()
    cfg = config(case, folder, threads)
    loader = MeshViewsLoader()
    with (
        metered(meter, MeshViewsLoader, "load_geometry", "load: geometry", "load: other"),
        metered(meter, mesh_views, "load_views_observations", "load: observations", "load: other"),
    ):
        meter.mark("load: other")
        cap = loader.load(folder, cfg, log)
    meter.mark(None)
    errors = None
    if fit:
        res = fit_capture(cfg, cap, MeteredStages(meter, log), log, torch.device("cpu"))
        meter.mark(None)
        if cap.truth is not None:
            errors = ground_truth_errors(res.pd, res.ps, res.sigma, cap.truth, res.estimated, res.counts["T_spec"] >= 2)
        del res
    result = ScaleResult(
        case,
        cap.surface.num_texels,
        cap.obs.num_lights,
        int(cap.obs.valid.sum()),
        int(cap.obs.valid.any(0).sum()),
        merged(meter.segments),
        max(s.peak_bytes for s in meter.segments),
        meter.resets,
        None,
        errors,
    )
    del cap
    if rays:
        meta, geom = loader.load_geometry(folder, cfg)
        result.rays = ray_rates(meta, geom, RayTracer(geom.mesh.vertices, geom.mesh.faces, threads=threads), cfg)
    return result


def merged(segments: list[Segment]) -> list[Segment]:
    """One row per stage name, in first-seen order: seconds summed, the largest peak."""
    rows: dict[str, Segment] = {}
    for s in segments:
        row = rows.setdefault(s.name, Segment(s.name, 0.0, 0))
        row.seconds += s.seconds
        row.cpu_seconds += s.cpu_seconds
        row.peak_bytes = max(row.peak_bytes, s.peak_bytes)
    return list(rows.values())


def _rays_line(r: RayRates) -> str:
    m = lambda rate: f"{rate / 1e6:.2f}"  # noqa: E731
    return (
        f"Camera-visibility rays ({r.rays:,} rays over all cameras; M rays/s): closest_hit as camera_view calls it "
        f"{m(r.ours)}, the whole camera_view call {m(r.camera_view)}, raw Embree 1 thread {m(r.raw_1t)}, "
        f"raw Embree {r.threads} thread(s) {m(r.raw_nt)}; ours / raw ({r.threads} thread(s)) "
        f"**{r.ours / r.raw_nt:.2f}**, whole camera_view / raw {r.camera_view / r.raw_nt:.2f}."
    )


def _errors_line(e: dict) -> str:
    f = lambda x: "n/a" if x is None else f"{x:.3f}"  # noqa: E731
    return (
        f"Against truth.npz: pd RMSE {f(e['pd_rmse'])} over {e['texels_estimated']:,} estimated texels; Ps, sigma "
        f"median relative errors {f(e['ps_median_rel_err'])}, {f(e['sigma_median_rel_err'])} over "
        f"{e['texels_spec_observed_twice']:,} texels with two or more highlight observations."
    )


def report(res: ScaleResult, command: str) -> str:
    """A markdown section: the case, the machine, the stage table, the ray rates and the errors."""
    c, gib = res.case, 1024**3
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}"
    lines = [
        f"### {c.name}: {res.texels:,} texels, {res.images} images of {c.width} x {c.height} px",
        "",
        f"`{command}` on {machine}. Observations: {res.valid_observations:,} valid of {res.images * res.texels:,} "
        f"(images x texels); {res.texels_seen:,} texels have one or more. Load average at the end (1, 5, 15 min): "
        + ", ".join(f"{x:.1f}" for x in os.getloadavg())
        + ".",
        "",
        "| stage | seconds | CPU seconds | peak resident GiB |",
        "|---|---:|---:|---:|",
    ]
    lines += [f"| {s.name} | {s.seconds:.1f} | {s.cpu_seconds:.1f} | {s.peak_bytes / gib:.2f} |" for s in res.segments]
    wall, cpu = sum(s.seconds for s in res.segments), sum(s.cpu_seconds for s in res.segments)
    lines.append(f"| **run** | {wall:.1f} | {cpu:.1f} | {res.peak_bytes / gib:.2f} |")
    if not res.resets:
        lines.append("\n(the kernel did not allow resetting the peak: each stage's peak is the run's so far)")
    if res.rays is not None:
        lines += ["", _rays_line(res.rays)]
    if res.errors is not None:
        lines += ["", _errors_line(res.errors)]
    return "\n".join(lines) + "\n"


def main(argv=None) -> ScaleResult:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", choices=sorted(CASES), default="quarter")
    ap.add_argument("--folder", type=Path, default=None, help="the capture folder (rendered there when new)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-rays", action="store_true", help="skip the camera-visibility rays measurement")
    ap.add_argument("--no-fit", action="store_true", help="stop after the loader")
    ap.add_argument("--markdown", type=Path, default=None, help="also write the report to this file")
    args = ap.parse_args(argv)
    case = CASES[args.case]
    folder = args.folder or Path(tempfile.gettempdir()) / f"torchrefl_mesh_views_scale_{case.name}"
    res = measure(
        case, folder, args.threads, rays=not args.no_rays, fit=not args.no_fit, log=lambda msg, echo=True: print(msg)
    )
    command = f"python scripts/bench_mesh_views_scale.py --case {case.name} --threads {args.threads}"
    command += " --no-fit" * args.no_fit + " --no-rays" * args.no_rays
    page = report(res, command)
    print(page)
    if args.markdown is not None:
        args.markdown.write_text(page)
    return res


if __name__ == "__main__":
    main()
