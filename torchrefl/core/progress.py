"""Stage timing and progress bars.

`Stages` times named stages (wall clock) for metrics.json and prints a summary table;
`bar` makes a tqdm progress bar that is silent when progress is off or stderr is not a terminal
and the run is short.
"""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager

from tqdm import tqdm


class Stages:
    """Collects wall-clock seconds per stage, in order, and the process's CPU seconds (all its threads) per stage."""

    def __init__(self, log=None):
        self.timing: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self.log = log
        self.failed: str | None = None  # the stage an exception or an interruption left
        self.completed: list[str] = []  # the stages that finished, in order

    @contextmanager
    def stage(self, name: str):
        start, cpu = time.perf_counter(), time.process_time()
        if self.log:
            self.log(f"[{name}] ...")
        outcome = "done"
        try:
            yield
            self.completed.append(name)
        except BaseException as exc:
            outcome = "interrupted" if isinstance(exc, KeyboardInterrupt) else "failed"
            self.failed = self.failed or name
            raise
        finally:
            self.timing[name] = self.timing.get(name, 0.0) + time.perf_counter() - start
            self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - cpu
            if self.log:
                self.log(f"[{name}] {outcome} {'in' if outcome == 'done' else 'after'} {self.timing[name]:.2f} s")

    def total(self) -> float:
        return sum(self.timing.values())


def bar(total: int, desc: str, enabled: bool = True, unit: str = "it"):
    """A tqdm progress bar on stderr (disabled when enabled is False)."""
    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        disable=not enabled,
        file=sys.stderr,
        leave=False,
        dynamic_ncols=True,
        mininterval=0.5,
    )
