"""A batch on Ray: one task per capture, each reserving the batch file's CPUs (and GPUs), results as they finish.

Ray starts on this machine inside the command unless `address` names a running cluster (`ray start --head`, then
`--address HEAD:6379`). Retry policy: a task whose worker process dies (killed, out of memory, the node lost) is
rerun by Ray up to `retries` times (the batch file's key, default 2), and the rerun continues the fit from its
checkpoints (torchrefl.train --resume); an exception inside a fit is not retried: it is that capture's failure,
recorded in its row. A task that exhausted its retries is failed with Ray's reason. Captures whose folder already
holds a whole run of the same config are skipped before any task starts.
"""

from __future__ import annotations

import importlib.util
import os
import time
from pathlib import Path
from typing import Callable

from torchrefl.batch.batch_file import BatchFile, task_threads
from torchrefl.batch.summary import Row, write_summary
from torchrefl.batch.task import completed_row, run_task, task_config
from torchrefl.core.progress import bar
from torchrefl.errors import ConfigError, TorchReflError

INSTALL = 'pip install "torchrefl[ray]"'


def require_ray():
    """The ray module; ConfigError saying how to install it when it is missing."""
    if importlib.util.find_spec("ray") is None:
        raise ConfigError(f"torchrefl.batch runs the fits on Ray, which is not installed: {INSTALL}")
    import ray

    return ray


def thread_env(threads: int) -> dict[str, str]:
    """The environment of a batch's worker processes: OpenMP, OpenBLAS and MKL pools of `threads` threads (set before
    the worker imports numpy and torch), as the fit's own torch and Embree threads (the config's `threads`)."""
    return {name: str(threads) for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


def _start(ray, address: str | None, num_cpus: int | None, threads: int = 1) -> bool:
    """Connect to the cluster at `address`, or start Ray here (num_cpus: the CPUs it offers; None: all), with worker
    processes of `threads` threads (thread_env); False when Ray was already running in this process (the caller's
    session is used and left running)."""
    if ray.is_initialized():
        return False
    env = thread_env(threads)
    kwargs = dict(include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    if address is None:
        package_root = str(Path(__file__).resolve().parents[2])  # workers import this torchrefl, as the driver does
        env["PYTHONPATH"] = os.pathsep.join(p for p in (package_root, os.environ.get("PYTHONPATH", "")) if p)
        ray.init(num_cpus=num_cpus, runtime_env={"env_vars": env}, **kwargs)
    else:
        ray.init(address=address, runtime_env={"env_vars": env}, **kwargs)
    return True


def _pending(batch: BatchFile) -> tuple[dict[str, Row], list]:
    """Rows of every task (skipped or pending, or failed for a config that does not load) and the tasks to run."""
    rows, todo = {}, []
    for task in batch.tasks:
        try:
            done = completed_row(task, task_config(batch.base, task, task_threads(batch)))
        except TorchReflError:
            done = None  # the task itself reports the error (e.g. a folder that tells no capture kind)
        rows[task.name] = done or Row(task.name, "pending", str(task.output))
        if done is None:
            todo.append(task)
    return rows, todo


def run_batch(
    batch: BatchFile,
    address: str | None = None,
    num_cpus: int | None = None,
    progress: bool = True,
    task_fn: Callable = run_task,
) -> list[Row]:
    """Fit every task of `batch` on Ray and return the rows (the summary files are rewritten as each finishes).
    address: a running Ray cluster (None: Ray starts here with num_cpus CPUs); task_fn(base, task, threads) -> Row
    is what each task runs (run_task)."""
    ray = require_ray()
    rows, todo = _pending(batch)
    write_summary(batch.output, list(rows.values()))
    started = _start(ray, address, num_cpus, task_threads(batch)) if todo else False
    try:
        remote = ray.remote(task_fn).options(
            num_cpus=batch.cpus_per_task,
            num_gpus=batch.gpus_per_task,
            max_retries=batch.retries,
            retry_exceptions=False,
        )
        threads = task_threads(batch)
        refs = {remote.remote(batch.base, task, threads): (task, time.perf_counter()) for task in todo}
        skipped = len(batch.tasks) - len(todo)
        with bar(len(batch.tasks), "batch", progress, unit="capture") as pb:
            pb.update(skipped)
            while refs:
                failed = sum(r.status == "failed" for r in rows.values())
                pb.set_postfix(done=pb.n - failed, failed=failed, running=len(refs), refresh=True)
                ready, _ = ray.wait(list(refs), num_returns=1)
                for ref in ready:
                    task, start = refs.pop(ref)
                    try:
                        row = ray.get(ref)
                    except ray.exceptions.RayError as exc:  # the worker died more often than retries allows
                        row = Row(
                            task.name,
                            "failed",
                            str(task.output),
                            error=f"worker lost {batch.retries + 1} times ({type(exc).__name__}): "
                            + str(exc).splitlines()[0],
                            seconds=round(time.perf_counter() - start, 2),
                        )
                    rows[task.name] = row
                    write_summary(batch.output, list(rows.values()))
                    pb.update(1)
            failed = sum(r.status == "failed" for r in rows.values())
            pb.set_postfix(done=pb.n - failed, failed=failed, running=0, refresh=True)
    finally:
        if started:
            ray.shutdown()
    return list(rows.values())
