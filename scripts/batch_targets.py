"""The measured targets of docs/results/batch.md: batch throughput with 1 and 2 workers, the 8-capture batch (a
broken folder, a worker killed mid-fit, a re-run), and a photon fit killed in its second outer iteration and resumed.

    python scripts/batch_targets.py [--work DIR] [--part throughput|targets|resume|all] [--fits N]
    python scripts/batch_targets.py --tiny      # the resume part only, on the tiny fold: seconds (the test's)

throughput: N small synthetic local fits (synthetic_seeds) with --num-cpus 1, then 2 (cpus_per_task 1: one torch
thread per fit). targets: 3 cylindrical_scan folders (the throughput run's captures), 1 copy of one with a damaged
scan.yaml, the DiLiGenT ball (16 lights; ../shared/data/diligent_ball) and 3 synthetic seeds; the worker fitting
seed-11 is SIGKILLed once its first checkpoint is written; then the same command again. resume: a small photon fit,
uninterrupted (seeds 0 and 1: the seed-to-seed spread), and seed 0 SIGKILLed during its second outer iteration then
continued with --resume. Prints the figures as JSON lines; needs Ray (pip install "torchrefl[ray]"). The runs are
killed by scripts/kill_runs.py's kill_when. --tiny: the resume part on the tiny fold of scripts/tiny_mode.py (2 outer
iterations), without the uninterrupted seeds, killed as soon as its second outer iteration starts (no Ray:
tests/batch runs a batch on Ray).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from torchrefl.batch import read_batch, run_batch  # noqa: E402

sys.path.insert(0, str(ROOT / "scripts"))
from kill_runs import kill_when  # noqa: E402
from tiny_mode import FOLD, TINY  # noqa: E402

SMALL = {
    "seed": 1,
    "capture": {"kind": "synthetic_cylindrical"},
    "synthetic": {
        "columns": 64,
        "rows": 50,
        "angle_step_deg": 5.625,
        "height_step_mm": 2.5,
        "size_mm": [30.0, 45.0, 25.0],
        "supersample": 1,
        "mesh_subdivisions": 4,
    },
    "selection": {"max_lights": 8},
    "fit": {"model": "local", "iterations": 30, "holdout": [1]},
    "output": {"progress": False, "map_lights": 0},
}
PHOTON = {
    "seed": 0,
    "capture": {"kind": "synthetic_cylindrical"},
    "synthetic": {
        "object": "vase",
        "columns": 48,
        "rows": 24,
        "angle_step_deg": 7.5,
        "height_step_mm": 5.0,
        "supersample": 1,
        "indirect_samples": 16,
        "noise_dn": 0.3,
    },
    "selection": {"num_lights": 6},
    "photon": {
        "photons_per_light": 5000,
        "outer_iterations": 3,
        "damping": 0.2,
        "smoothing": 1.0,
        "specular_gather": 0,
    },
    "fit": {"model": "photon", "iterations": 10, "holdout": [2]},
    "output": {"progress": False, "map_lights": 0},
}
BALL = ROOT / ".." / "shared" / "data" / "diligent_ball"
PY = [sys.executable]


def emit(**figures) -> None:
    print(json.dumps(figures), flush=True)


def ray_start_s(workers: int) -> float:
    """Seconds for Ray to start here, run one empty task on a fresh worker and stop: the batch's fixed cost."""
    from torchrefl.batch.runner import _start, require_ray

    ray = require_ray()
    start = time.perf_counter()
    _start(ray, None, workers)
    ray.get(ray.remote(lambda: 0).remote())
    ray.shutdown()
    return time.perf_counter() - start


def throughput(work: Path, fits: int) -> None:
    (work / "small.yaml").write_text(yaml.safe_dump(SMALL))
    for workers in (1, 2):
        fixed = ray_start_s(workers)
        doc = {"base": "small.yaml", "synthetic_seeds": list(range(1, fits + 1)), "output": f"out{workers}"}
        shutil.rmtree(work / f"out{workers}", ignore_errors=True)
        (work / f"batch{workers}.yaml").write_text(yaml.safe_dump(doc))
        start = time.perf_counter()
        rows = run_batch(read_batch(work / f"batch{workers}.yaml"), num_cpus=workers, progress=False)
        wall = time.perf_counter() - start
        fit_s = [r.seconds for r in rows if r.seconds]
        emit(
            part="throughput",
            workers=workers,
            fits=fits,
            complete=sum(r.status == "complete" for r in rows),
            wall_s=round(wall, 1),
            captures_per_hour=round(3600 * fits / wall, 1),
            ray_start_s=round(fixed, 1),
            captures_per_hour_after_start=round(3600 * fits / (wall - fixed), 1),
            mean_fit_s=round(sum(fit_s) / max(len(fit_s), 1), 1),
            mean_fit_cpu_s=round(sum(r.cpu_seconds or 0 for r in rows) / max(len(rows), 1), 1),
        )


def targets(work: Path) -> None:
    (work / "small.yaml").write_text(yaml.safe_dump(SMALL))
    caps = work / "caps"
    caps.mkdir(exist_ok=True)
    for seed in (1, 2, 3):
        shutil.copytree(work / "out1" / f"seed-{seed}" / "capture", caps / f"scan{seed}", dirs_exist_ok=True)
    shutil.copytree(caps / "scan1", caps / "broken", dirs_exist_ok=True)
    (caps / "broken" / "scan.yaml").write_text("columns: [64\n")  # damaged: not YAML
    lights = list(range(0, 96, 6))
    ball = {
        "path": str(BALL.resolve()),
        "overrides": [
            f"capture.light_subset={lights}",
            "fit.holdout=[3]",
            "fit.specular=shared",
            "reflectance.ps_max=1.0",
        ],
    }
    doc = {
        "base": "small.yaml",
        "captures": ["caps/*", ball],
        "synthetic_seeds": [11, 12, 13],
        "output": "targets",
        "retries": 2,
    }
    (work / "targets.yaml").write_text(yaml.safe_dump(doc))
    cmd = [*PY, "-m", "torchrefl.batch", str(work / "targets.yaml"), "--num-cpus", "2", "--quiet"]
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    has_checkpoint = lambda staging: any((staging / "checkpoint").glob("*.pt"))
    killed = kill_when(work / "targets", "seed-11", has_checkpoint, poll_s=0.5)
    out, err = proc.communicate()
    wall = time.perf_counter() - start
    rows = json.loads((work / "targets" / "summary.json").read_text())
    log = (work / "targets" / "seed-11" / "log.txt").read_text() if (work / "targets" / "seed-11").is_dir() else ""
    emit(
        part="targets",
        exit=proc.returncode,
        wall_s=round(wall, 1),
        killed_pid=killed,
        seed11_resumed="continuing the unfinished run" in log,
        last_line=out.strip().splitlines()[-1] if out.strip() else err[-500:],
        rows=[(r["name"], r["status"], r["model"], r["seconds"], r["error"][:160]) for r in rows],
    )
    start = time.perf_counter()
    again = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    rows = json.loads((work / "targets" / "summary.json").read_text())
    emit(
        part="targets-rerun",
        exit=again.returncode,
        wall_s=round(time.perf_counter() - start, 1),
        last_line=again.stdout.strip().splitlines()[-1],
        statuses=[(r["name"], r["status"]) for r in rows],
    )


def _metrics(folder: Path) -> dict:
    m = json.loads((folder / "metrics.json").read_text())
    return {
        "holdout_mean_abs_diff_8bit": m["holdout"]["mean_abs_diff_8bit"],
        "pd_rmse": m["ground_truth"]["pd_rmse"],
        "ps_rmse": m["ground_truth"]["ps_rmse"],
        "sigma_rmse": m["ground_truth"]["sigma_rmse"],
        "kept_refresh": m["photon"]["kept_refresh"],
    }


class SecondOuterIteration:
    """kill_when's moment: outer iteration 1 is done and its checkpoint saved (checkpoint/outer.pt rewritten since
    the last look before the log said 'photon refresh 1', which comes just before that save): iteration 2 runs."""

    def __init__(self):
        self.before: tuple[int, int] | None = None  # outer.pt's (inode, mtime) at the last look before refresh 1

    def __call__(self, staging: Path) -> bool:
        outer = staging / "checkpoint" / "outer.pt"
        stamp = (outer.stat().st_ino, outer.stat().st_mtime_ns) if outer.is_file() else None
        log = staging / "log.txt"
        if not (log.is_file() and "photon refresh 1:" in log.read_text()):
            self.before = stamp
            return False
        return stamp is not None and stamp != self.before


def resume(work: Path, config: Path | None = None, overrides: tuple[str, ...] = (), seeds=(0, 1), after_s=2.0) -> None:
    """A photon fit (`config` with `overrides`; None: PHOTON) killed in its second outer iteration, `after_s` after
    it starts, and resumed; beside it the uninterrupted fits of `seeds`."""
    if config is None:
        config = work / "photon.yaml"
        config.write_text(yaml.safe_dump(PHOTON))
    train = [*PY, "-m", "torchrefl.train", str(config), *overrides, "--quiet"]
    for seed in seeds:
        subprocess.run([*train, f"seed={seed}", f"output.dir={work / f'whole{seed}'}"], cwd=ROOT, check=True)
    target = work / "killed"
    start = time.perf_counter()
    proc = subprocess.Popen([*train, f"output.dir={target}"], cwd=ROOT)
    killed = kill_when(work, target.name, SecondOuterIteration(), proc, poll_s=0.05, after_s=after_s)
    killed_at = None if killed is None else time.perf_counter() - start
    start = time.perf_counter()
    subprocess.run([*train, f"output.dir={target}", "--resume"], cwd=ROOT, check=True)
    resumed_s = time.perf_counter() - start
    after = (target / "log.txt").read_text().split("continuing")[-1].splitlines()
    emit(
        part="resume",
        killed_after_s=None if killed_at is None else round(killed_at, 1),
        resumed_run_s=round(resumed_s, 1),
        refreshes_after_resume=[line.split("] ")[1].split(":")[0] for line in after if "photon refresh" in line],
        **{f"whole_seed{seed}": _metrics(work / f"whole{seed}") for seed in seeds},
        killed_and_resumed_seed0=_metrics(target),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, help="working folder (default: a new temporary one)")
    parser.add_argument("--part", choices=("throughput", "targets", "resume", "all"), default="all")
    parser.add_argument("--fits", type=int, default=6, help="fits in the throughput batch")
    parser.add_argument("--tiny", action="store_true", help="the resume part on the tiny fold: seconds")
    args = parser.parse_args(argv)
    work = (args.work or Path(tempfile.mkdtemp(prefix="batch-targets-"))).absolute()
    work.mkdir(parents=True, exist_ok=True)
    emit(work=str(work))
    if args.tiny:
        resume(work, FOLD, (*TINY, "fit.model=photon", "photon.outer_iterations=2"), seeds=(), after_s=0.0)
        return 0
    if args.part in ("throughput", "all"):
        throughput(work, args.fits)
    if args.part in ("targets", "all"):
        targets(work)
    if args.part in ("resume", "all"):
        resume(work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
