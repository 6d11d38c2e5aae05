"""SIGKILL a real `python -m torchrefl.train` at staged moments and check what load_run makes of the folder.

    python scripts/kill_runs.py [--work DIR]
    python scripts/kill_runs.py --tiny      # one moment (the staging folder appears) on a fresh folder (the test's)

Moments, found by polling the run's staging folder (.NAME.staging-PID beside the target): the staging folder
appears; the synthetic capture's scan.yaml is written; the first texture is rendered; params.npz is written
(outputs stage); the completeness marker is written (the commit). Each moment is tried on a fresh target and
on a target holding an earlier complete run (with --overwrite). After each kill, load_run(target) must either
raise a TorchReflError (fresh target) or load one whole run: the earlier one unchanged, or the new one complete.
Exit status 0 when every trial holds.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from torchrefl import TorchReflError, load_run  # noqa: E402
from torchrefl.report.run_folder import STAGING  # noqa: E402

CONFIG = {
    "seed": 1,
    "capture": {"kind": "synthetic_cylindrical"},
    "synthetic": {
        "columns": 96,
        "rows": 80,
        "angle_step_deg": 3.75,
        "height_step_mm": 2.5,
        "size_mm": [50.0, 70.0, 42.0],
        "supersample": 1,
        "mesh_subdivisions": 4,
    },
    "selection": {"max_lights": 6},
    "fit": {"iterations": 10},
    "output": {"progress": False, "map_lights": 2},
}
MOMENTS = {
    "staging folder created": lambda s: s.is_dir(),
    "capture scan.yaml written": lambda s: (s / "capture" / "scan.yaml").is_file(),
    "first texture rendered": lambda s: any((s / "capture" / "textures").glob("*.png")),
    "params.npz written": lambda s: (s / "params.npz").is_file(),
    "marker written (commit)": lambda s: (s / "run_complete.json").is_file(),
}


def train(config: Path, target: Path, overwrite: bool) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "torchrefl.train", str(config), f"output.dir={target}", "--quiet"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen(
        cmd + (["--overwrite"] if overwrite else []), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )


def kill_when(
    parent: Path,
    name: str,
    reached,
    proc: subprocess.Popen | None = None,
    timeout_s: float = 1800.0,
    poll_s: float = 0.001,
    after_s: float = 0.0,
) -> int | None:
    """SIGKILL the run into parent/NAME as soon as `reached(staging)` holds for its staging folder
    (`.NAME.staging-PID`, torchrefl.report.run_folder.STAGING), `after_s` seconds later. `proc`: the run, started
    here: only its own staging folder counts; None (a batch's Ray worker): any run's, the PID killed read from the
    folder's name. Returns the PID killed; None if `proc` ended first or `timeout_s` passed. The scripts' one way
    to kill a run at a moment."""
    pattern = STAGING.format(name=name, pid="*" if proc is None else proc.pid)
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and (proc is None or proc.poll() is None):
        for staging in parent.glob(pattern):
            if reached(staging):
                time.sleep(after_s)
                pid = int(staging.name.rsplit("-", 1)[1])
                os.kill(pid, signal.SIGKILL)
                if proc is not None:
                    proc.wait()
                return pid
        time.sleep(poll_s)
    return None


def kill_at(config: Path, target: Path, overwrite: bool, reached) -> str:
    """Start a run, SIGKILL it when `reached(staging)` holds; returns 'killed' or 'finished first'."""
    proc = train(config, target, overwrite)
    killed = kill_when(target.parent, target.name, reached, proc)
    proc.wait()
    return "killed" if killed is not None else "finished first"


def digest(folder: Path) -> str:
    return hashlib.sha256((folder / "params.npz").read_bytes() + (folder / "metrics.json").read_bytes()).hexdigest()


def verdict(target: Path, earlier: str | None) -> tuple[bool, str]:
    """(holds, what load_run gave)."""
    try:
        run = load_run(target)
    except TorchReflError as exc:
        return earlier is None, f"named error: {str(exc)[:90]}"
    now = digest(target)
    if earlier is not None and now == earlier:
        return True, "the earlier run, unchanged"
    return True, f"a whole new run (model {run.metrics['model']}, {run.metrics['lights']} lights)"


#: --tiny: the first moment on a fresh folder only (no reference run: one process, killed as it starts its work)
TINY_MOMENT = "staging folder created"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default=None, help="scratch folder (default: a temporary one, removed at the end)")
    ap.add_argument("--tiny", action="store_true", help=f"the moment '{TINY_MOMENT}' on a fresh folder only: seconds")
    args = ap.parse_args(argv)
    work = Path(args.work or tempfile.mkdtemp(prefix="kill_runs_"))
    work.mkdir(parents=True, exist_ok=True)
    config = work / "tiny.yaml"
    config.write_text(yaml.safe_dump(CONFIG))
    earlier_run, earlier = work / "earlier", None
    if not args.tiny:
        if not earlier_run.is_dir():
            assert train(config, earlier_run, False).wait() == 0, "the reference run failed"
        earlier = digest(earlier_run)
    ok_all = True
    moments = {TINY_MOMENT: MOMENTS[TINY_MOMENT]} if args.tiny else MOMENTS
    for name, reached in moments.items():
        for with_earlier in (False,) if args.tiny else (False, True):
            target = work / f"t_{len(os.listdir(work))}"
            if with_earlier:
                shutil.copytree(earlier_run, target)
            outcome = kill_at(config, target, with_earlier, reached)
            ok, what = verdict(target, earlier if with_earlier else None)
            ok_all &= ok
            print(
                f"{'ok  ' if ok else 'FAIL'} {name:<28} {'earlier run' if with_earlier else 'fresh folder':<12} "
                f"{outcome:<15} load_run: {what}",
                flush=True,
            )
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if ok_all else 1


if __name__ == "__main__":
    sys.exit(main())
