"""Which unfinished run of a config `--resume` continues (python -m torchrefl.train CONFIG --resume).

An unfinished run into output folder NAME is either the staging folder `.NAME.staging-PID` of a run that was
killed (its process is gone) or `NAME.failed`, the files of a run that stopped on an error. One can be continued
when it holds checkpoints (torchrefl.core.checkpoints) and its config.yaml is the config being run, byte for
byte; of those the one whose latest checkpoint is newest is chosen. A run whose config differs is never
continued (that would mix two runs in one folder): it is left alone, and the run starts anew.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from torchrefl.core.checkpoints import FOLDER, has_checkpoints
from torchrefl.report.run_folder import FAILED, REPLACED, STAGING, pid_alive
from torchrefl.report.run_marker import CONFIG


@dataclass(frozen=True)
class Resumable:
    """The run --resume continues (None: none), and the sentence the run's log starts with saying which."""

    folder: Path | None
    note: str


def unfinished_runs(target: Path) -> list[Path]:
    """The unfinished runs into `target` that hold checkpoints: killed runs' staging folders and NAME.failed."""
    target = Path(target)
    if not target.parent.is_dir():
        return []
    prefix = STAGING.format(name=target.name, pid="")
    pids = {p: p.name[len(prefix) :] for p in target.parent.glob(f"{prefix}*") if not p.name.endswith(REPLACED)}
    killed = [p for p, pid in pids.items() if pid.isdigit() and not pid_alive(int(pid))]
    failed = target.parent / FAILED.format(name=target.name)
    return [p for p in [*killed, failed] if p.is_dir() and has_checkpoints(p)]


def _latest_checkpoint(run: Path) -> float:
    return max(p.stat().st_mtime for p in (run / FOLDER).glob("*.pt"))


def resumable_run(target: Path, config_text: str) -> Resumable:
    """The newest unfinished run into `target` whose config.yaml is `config_text` (see the module's rule)."""
    runs = sorted(unfinished_runs(target), key=_latest_checkpoint, reverse=True)
    same = [p for p in runs if (p / CONFIG).is_file() and (p / CONFIG).read_text(encoding="utf-8") == config_text]
    if same:
        points = sorted(p.stem for p in (same[0] / FOLDER).glob("*.pt"))
        return Resumable(same[0], f"resume: continuing the unfinished run {same[0]} (checkpoints: {', '.join(points)})")
    if runs:
        return Resumable(
            None,
            f"resume: {len(runs)} unfinished run(s) into {target} (e.g. {runs[0].name}) were made with another config "
            "and are not continued; starting anew",
        )
    return Resumable(None, f"resume: no unfinished run into {target} holds a checkpoint; starting anew")
