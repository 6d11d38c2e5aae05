"""How long the bundled configs take, end to end, as a user runs them: the one source of the times the docs quote.

Runs each config with `python -m torchrefl.train` in a subprocess (a fresh interpreter, imports included), records
the wall time, the run's own stage timings (metrics.json `timing_s`) and the machine (CPU model, cores, threads the
runs use, load average before the run, torch and Python versions), and writes a markdown table,
docs/results/timings.md by default. Run it alone on the machine: other jobs on the same cores change every number.

    python scripts/bench_configs.py                       # default, quick, diligent_ball, mesh_views (minutes)
    python scripts/bench_configs.py --all                 # also concave, fold, mesh_views_concave (long)
    python scripts/bench_configs.py --configs quick --set synthetic.rows=32 --out /tmp/timings.md   # a smoke test

diligent_ball needs the DiLiGenT ball folder (not shipped with torchrefl): --ball PATH, by default
../shared/data/diligent_ball beside the repository when it is there; without it the row says it was skipped.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import torch

import torchrefl
from torchrefl.config import load_config

ROOT = Path(__file__).resolve().parents[1]
FIRST = ["default", "quick", "diligent_ball", "mesh_views"]
#: how the tables show the ball's folder (the README's placeholder, not this machine's path)
BALL_SHOWN = "capture.path=/path/to/DiLiGenT/pmsData/ballPNG"
LONG = ["concave", "fold", "mesh_views_concave"]
SHARED_BALL = ROOT / ".." / "shared" / "data" / "diligent_ball"


@dataclass(frozen=True)
class Machine:
    """What the times were measured on."""

    cpu: str
    cores: int
    threads: int
    torch: str
    python: str
    system: str


@dataclass(frozen=True)
class Timing:
    """One config's run: its command, wall time, stage timings (s) and the load average before it started."""

    config: str
    command: str
    wall_s: float | None
    stages: dict[str, float]
    load_before: float
    note: str = ""


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo on Linux; platform's answer elsewhere)."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def machine(threads: int) -> Machine:
    return Machine(
        cpu=cpu_model(),
        cores=os.cpu_count() or 0,
        threads=threads,
        torch=torch.__version__,
        python=platform.python_version(),
        system=f"{platform.system()} {platform.machine()}",
    )


def run_config(name: str, extra: list[str], work: Path, ball: Path | None) -> Timing:
    """One end-to-end run of configs/NAME.yaml into work/NAME, timed from outside."""
    args = [f"configs/{name}.yaml"]
    if name == "diligent_ball":
        if ball is None or not ball.is_dir():
            return Timing(name, "", None, {}, os.getloadavg()[0], f"skipped: no DiLiGenT ball folder ({ball})")
        args.append(f"capture.path={ball}")
    out = work / name
    args += [f"output.dir={out}", "output.progress=false", *extra, "--quiet", "--overwrite"]
    load = os.getloadavg()[0]
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "torchrefl.train", *args], cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - start
    shown = "python -m torchrefl.train " + " ".join(
        BALL_SHOWN if a.startswith("capture.path=") else shlex.quote(a) for a in args if not a.startswith("output.")
    )
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["(no output)"]
        return Timing(name, shown, None, {}, load, f"failed (exit {done.returncode}): {tail[0]}")
    metrics = json.loads((out / "metrics.json").read_text())
    return Timing(name, shown, wall, metrics.get("timing_s", {}), load)


def table(timings: list[Timing], m: Machine, how: str) -> str:
    """The markdown page: the machine, how it was produced (`how`: the bench command), one row per config."""
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "# Timings of the bundled configs",
        "",
        f"Written by `{how}` on {when}; every time the README and docs quote for these runs comes from here. "
        "Each run is a fresh `python -m torchrefl.train` process (imports included); `wall` is measured from "
        "outside, the stages are the run's own `metrics.json` `timing_s`.",
        "",
        f"Machine: {m.cpu}, {m.cores} cores ({m.system}), runs with `threads` {m.threads}; torch {m.torch}, "
        f"Python {m.python}. `load` is the 1-minute load average before the run: above about 0.5 other jobs shared "
        "the cores, and the times are longer than on a quiet machine.",
        "",
        "| config | command | wall (s) | stages (s) | load |",
        "|---|---|---|---|---|",
    ]
    for t in timings:
        wall = f"{t.wall_s:.1f}" if t.wall_s is not None else t.note
        stages = ", ".join(f"{k} {v:.1f}" for k, v in t.stages.items() if k != "total")
        if "total" in t.stages:
            stages += f"; total {t.stages['total']:.1f}"
        command = f"`{t.command}`" if t.command else ""
        lines.append(f"| {t.config} | {command} | {wall} | {stages} | {t.load_before:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configs", nargs="+", default=None, help=f"bundled config names (default: {' '.join(FIRST)})")
    ap.add_argument("--all", action="store_true", help=f"also the long ones: {' '.join(LONG)} (about 10 min each)")
    ap.add_argument("--ball", type=Path, default=SHARED_BALL if SHARED_BALL.is_dir() else None, help="DiLiGenT ball")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", help="overrides for every run")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "timings.md", help="markdown table")
    ap.add_argument("--work", type=Path, default=ROOT / "outputs" / "bench_configs", help="run folders")
    a = ap.parse_args(argv)
    names = (a.configs or FIRST) + (LONG if a.all else [])
    for name in names:
        if not (ROOT / "configs" / f"{name}.yaml").is_file():
            ap.error(f"configs/{name}.yaml: no such bundled config")
    threads = load_config(ROOT / "configs" / f"{names[0]}.yaml", a.set).threads
    print(f"torchrefl {torchrefl.__version__}: timing {', '.join(names)}", file=sys.stderr)
    timings = []
    for name in names:
        t = run_config(name, a.set, a.work.resolve(), a.ball.resolve() if a.ball else None)
        print(f"{name}: {f'{t.wall_s:.1f} s' if t.wall_s is not None else t.note}", file=sys.stderr)
        timings.append(t)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    how = "python scripts/bench_configs.py" + (f" --configs {' '.join(a.configs)}" if a.configs else "")
    how += (" --all" if a.all else "") + "".join(f" --set {shlex.quote(kv)}" for kv in a.set)
    a.out.write_text(table(timings, machine(threads), how))
    print(f"wrote {a.out}")
    return 0 if all(t.wall_s is not None or t.note.startswith("skipped") for t in timings) else 1


if __name__ == "__main__":
    sys.exit(main())
