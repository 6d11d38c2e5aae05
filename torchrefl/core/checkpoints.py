"""A run's checkpoints: what a killed or failed run needs to continue (python -m torchrefl.train --resume).

They live in the run's staging folder, under checkpoint/, one file per point, each written whole or not at all
(core.atomic_files): `capture.pt` (the capture the fit reads), `initialise.pt` (the closed-form start corrected by
the transport level), `outer.pt` (the refinement after each outer iteration: texel parameters, the objective's
priors, the loss history, the level's own state such as the photon caches, the torch random state) and `fit.pt`
(the finished fit). A resumed run loads the newest it reaches and redoes the rest; the precompute stage (form
factors, tracers: not picklable) is always redone. The refinement's optimiser starts anew at every refit step, so
there is no optimiser state to keep. The folder is removed before the run completes (it is never part of a
finished run).
"""

from __future__ import annotations

import io
import shutil
from pathlib import Path
from typing import Any, Callable, TypeVar

import torch

from torchrefl.core.atomic_files import atomic_write_bytes
from torchrefl.errors import RunFolderError

FOLDER = "checkpoint"
_T = TypeVar("_T")


class Checkpoints:
    """The checkpoints of the run in staging folder `run`; `log` says what a resumed run takes from them.

    enabled=False: nothing is saved or loaded (a run that cannot resume, e.g. the Python API's one-off fits)."""

    def __init__(self, run: Path, log: Callable[[str], None] = lambda msg: None, enabled: bool = True):
        self.folder = Path(run) / FOLDER
        self.log = log
        self.enabled = enabled
        self.saved: list[str] = []  # the points saved by this process, in order

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.pt"

    def save(self, name: str, state: Any) -> None:
        """Write checkpoint `name` atomically (torch.save of `state`)."""
        if not self.enabled:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        torch.save(state, buf)
        atomic_write_bytes(self.path(name), buf.getvalue())
        self.saved.append(name)

    def load(self, name: str) -> Any | None:
        """The state of checkpoint `name`, or None when there is none (RunFolderError when it cannot be read)."""
        path = self.path(name)
        if not self.enabled or not path.is_file():
            return None
        try:
            return torch.load(path, weights_only=False)
        except Exception as exc:  # a checkpoint is written whole: a damaged one was changed after the run
            raise RunFolderError(
                f"{path}: damaged checkpoint ({type(exc).__name__}: {exc}); rerun without --resume"
            ) from None

    def point(self, name: str, compute: Callable[[], _T]) -> _T:
        """The value checkpoint `name` holds (logged as resumed), else compute() saved as `name`."""
        state = self.load(name)
        if state is not None:
            self.log(f"resume: {name} from the checkpoint ({self.path(name).name})")
            return state
        value = compute()
        self.save(name, value)
        return value

    def remove(self) -> None:
        """Delete every checkpoint (the run completed: they are not part of its folder)."""
        shutil.rmtree(self.folder, ignore_errors=True)


def has_checkpoints(run: Path) -> bool:
    """Whether the (unfinished) run folder `run` holds at least one checkpoint."""
    folder = Path(run) / FOLDER
    return folder.is_dir() and any(folder.glob("*.pt"))
