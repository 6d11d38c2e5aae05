"""Where the photon and radiosity levels spend time and memory, stage by stage, in one fit.

Fits a config (default configs/fold.yaml; --capture fits an existing capture folder) with the library's functions
wrapped by a profiler: every call of a wrapped function is a stage, named by the path of the wrapped calls it sits in
(e.g. `refresh > cache > tracing`), and its time is what it spends outside the stages nested in it (exclusive). Per
stage: calls, wall seconds, CPU seconds of the process (all its threads: Embree's and torch's), and the peak resident
memory while it ran (Linux: the kernel's high-water mark, reset at every stage boundary, so the run's own
metrics.json `peak_memory_mb` is the last stage's; the largest stage peak is the run's). On a machine shared with
other jobs the wall time grows with their load and the CPU time much less: compare CPU seconds between runs.

    python scripts/profile_levels.py [--capture DIR] [--set KEY=VALUE ...] [--out DIR]
    python scripts/profile_levels.py --tiny      # the tiny fold (scripts/tiny_mode.py): seconds, the test's mode

Writes profile.json and prints a markdown table (docs/results/performance.md, "Where the interreflection levels
spend time and memory").
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

import torchrefl
from torchrefl.core.memory import peak_resident_mb, reset_peak
from torchrefl.fit import pipeline, reestimate  # modules (torchrefl.fit the attribute is the fit function)
from torchrefl.transport import photon_refresh as refresh
from torchrefl.transport.levels import photon, radiosity
from torchrefl.transport.photon_trace import PhotonTracer

sys.path.insert(0, str(Path(__file__).parent))
from tiny_mode import FOLD, TINY  # noqa: E402

#: (owner, attribute, stage name): the functions whose calls are stages
WRAPPED = [
    (radiosity.RadiosityLevel, "prepare", "radiosity prepare"),
    (radiosity, "form_factors_for_surface", "form factors"),
    (radiosity, "emitter_maps", "emitter maps"),
    (radiosity.RadiosityLevel, "start", "Method II start"),
    (radiosity.RadiosityLevel, "indirect", "radiosity solve"),
    (radiosity.RadiosityLevel, "radiance", "radiosity solve"),
    (photon.PhotonLevel, "prepare", "photon prepare"),
    (photon.PhotonLevel, "refresh", "refresh"),
    (photon, "average_caches", "cache average"),
    (refresh.PhotonRefresh, "cache", "cache"),
    (PhotonTracer, "trace", "tracing"),
    (refresh, "build_cache", "reduction into the cache"),
    (refresh.PhotonRefresh, "_add_gather", "specular gather"),
    (pipeline, "reestimate", "re-estimation"),
    (reestimate, "profile_search", "sigma search"),
    (reestimate, "profiled_fit", "sigma profile"),
    (reestimate, "settle_outliers", "lobe consensus"),
    (reestimate, "lend_lobes", "lobes lent by colour"),
    (reestimate, "material_lobes", "material lobes"),
    (photon.PhotonLevel, "indirect_terms", "indirect terms"),
    (pipeline, "levenberg_marquardt", "refit (LM)"),
    (pipeline, "refine", "refit"),
    (photon.PhotonLevel, "render", "final images"),
]


@dataclass
class Stage:
    calls: int = 0
    wall_s: float = 0.0
    cpu_s: float = 0.0
    peak_mb: float = 0.0


class Profiler:
    """Exclusive wall and CPU seconds and peak resident memory per stage path, from wrapped functions."""

    def __init__(self):
        self.stages: dict[str, Stage] = {}
        self.stack: list[str] = ["(outside the wrapped stages)"]
        self._mark = (time.perf_counter(), time.process_time())
        self._undo: list = []

    def _switch(self) -> None:
        """Charge the interval since the last boundary to the stage on top of the stack."""
        wall, cpu = time.perf_counter(), time.process_time()
        s = self.stages.setdefault(" > ".join(self.stack[1:]) or self.stack[0], Stage())
        s.wall_s += wall - self._mark[0]
        s.cpu_s += cpu - self._mark[1]
        s.peak_mb = max(s.peak_mb, peak_resident_mb())
        reset_peak()
        self._mark = (wall, cpu)

    def wrap(self, owner, attr: str, name: str) -> None:
        plain = getattr(owner, attr)
        profiler = self

        def staged(*args, **kwargs):
            profiler._switch()
            profiler.stack.append(name)
            profiler.stages.setdefault(" > ".join(profiler.stack[1:]), Stage()).calls += 1
            try:
                return plain(*args, **kwargs)
            finally:
                profiler._switch()
                profiler.stack.pop()

        setattr(owner, attr, staged)
        self._undo.append((owner, attr, plain))

    def unwrap(self) -> None:
        for owner, attr, plain in reversed(self._undo):
            setattr(owner, attr, plain)
        self._undo.clear()


def table(stages: dict[str, Stage], fit_wall: float, fit_cpu: float) -> str:
    """The stages as a markdown table, with each one's share of the CPU seconds of all stages."""
    total = sum(s.cpu_s for s in stages.values())
    lines = [
        "| stage (nested: a > b) | calls | wall s | CPU s | CPU share | peak resident MiB |",
        "|---|---|---|---|---|---|",
    ]
    for name, s in stages.items():
        share = f"{s.cpu_s / total:.1%}" if total > 0 else "-"
        lines.append(f"| {name} | {s.calls} | {s.wall_s:.1f} | {s.cpu_s:.1f} | {share} | {s.peak_mb:.0f} |")
    lines.append(f"| fit stages (precompute + initialise + fit) | | {fit_wall:.1f} | {fit_cpu:.1f} | | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=FOLD)
    ap.add_argument("--capture", type=Path, default=None, help="fit this capture folder instead of rendering one")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", help="config overrides")
    ap.add_argument("--tiny", action="store_true", help="the tiny fold: seconds (scripts/tiny_mode.py)")
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: a temporary one)")
    args = ap.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="profile_levels_"))
    over = (TINY if args.tiny else ["output.progress=false"]) + list(args.set) + [f"output.dir={out / 'run'}"]
    if args.capture is not None:
        over += ["capture.kind=cylindrical_scan", f"capture.path={args.capture.resolve()}"]
    cfg = torchrefl.load_config(args.config, over)
    profiler = Profiler()
    for owner, attr, name in WRAPPED:
        profiler.wrap(owner, attr, name)
    try:
        metrics = torchrefl.fit(cfg, overwrite=True).metrics
    finally:
        profiler._switch()
        profiler.unwrap()
    keys = ("precompute", "initialise", "fit")
    fit_wall = sum(metrics["timing_s"].get(k, 0.0) for k in keys)
    fit_cpu = sum(metrics["cpu_s"].get(k, 0.0) for k in keys)
    report = {
        "config": args.config.name,
        "overrides": args.set,
        "threads": cfg.threads,
        "torch_threads": torch.get_num_threads(),
        "model": metrics["model"],
        "texels": metrics["texels"],
        "lights": metrics["lights"],
        "timing_s": metrics["timing_s"],
        "cpu_s": metrics["cpu_s"],
        "peak_memory_mb": max(st.peak_mb for st in profiler.stages.values()),
        "photon": metrics.get("photon"),
        "ground_truth": metrics.get("ground_truth"),
        "holdout": metrics.get("holdout"),
        "stages": {k: asdict(v) for k, v in profiler.stages.items()},
    }
    (out / "profile.json").write_text(json.dumps(report, indent=2))
    print(
        f"{args.config.name}: {metrics['texels']} texels, {metrics['lights']} lights, model {metrics['model']}; "
        f"peak resident memory {report['peak_memory_mb']:.0f} MiB (the largest stage peak)"
    )
    print(table(profiler.stages, fit_wall, fit_cpu))
    print(f"written {out / 'profile.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
