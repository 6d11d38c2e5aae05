"""One capture's fit as a batch task: what Ray runs on a worker, and what decides that a capture is already done."""

from __future__ import annotations

import json
import time
import traceback
from pathlib import Path

from torchrefl.batch.batch_file import BatchTask
from torchrefl.batch.summary import Row, row_of
from torchrefl.config import Config, load_config, run_config_text
from torchrefl.errors import RunFolderError, TorchReflError
from torchrefl.report.run_marker import CONFIG, verify_run_folder
from torchrefl.run import run


def task_config(base: str, task: BatchTask, threads: int) -> Config:
    """The config of one task: base with the task's overrides and `threads` torch / Embree threads."""
    return load_config(base, [*task.train_overrides(), f"threads={threads}"])


def completed_row(task: BatchTask, cfg: Config) -> Row | None:
    """The `skipped` row when the task's folder holds a whole run (marker and files valid) of this very config;
    None otherwise (not run, unfinished, damaged or another config: the fit runs)."""
    try:
        verify_run_folder(task.output)
    except RunFolderError:
        return None
    text = run_config_text(cfg)
    if (task.output / CONFIG).read_text(encoding="utf-8") != text:
        return None
    metrics = json.loads((task.output / "metrics.json").read_text())
    return row_of(task.name, "skipped", task.output, metrics, None, attempts=0)


def run_task(base: str, task: BatchTask, threads: int) -> Row:
    """Fit one task (resuming its unfinished run when there is one) and return its row; any error is caught and
    recorded in the row (a named error's message; else the exception's type, message and where it was raised), so
    one failing capture never stops the batch."""
    start, cpu = time.perf_counter(), time.process_time()
    try:
        cfg = task_config(base, task, threads)
        metrics = run(cfg, quiet=True, resume=True)
        seconds = time.perf_counter() - start
        return row_of(task.name, "complete", task.output, metrics, seconds, cpu=time.process_time() - cpu)
    except TorchReflError as exc:
        error = str(exc)
    except Exception as exc:  # a crash of one fit is that capture's failure, not the batch's
        where = traceback.extract_tb(exc.__traceback__)[-1]
        error = f"{type(exc).__name__}: {exc} (at {Path(where.filename).name}:{where.lineno})"
    seconds = round(time.perf_counter() - start, 2)
    return Row(task.name, "failed", str(task.output), error=error, seconds=seconds, attempts=1)
