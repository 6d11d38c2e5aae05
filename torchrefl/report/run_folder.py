"""A run folder as a transaction: checked before any work, written in a staging folder, moved into place whole.

The rule (also in docs/outputs.md's terms): a run writes into `.NAME.staging-PID` beside the target
folder NAME. When it completes, the completeness marker (run_marker) is written last and the staging
folder takes the target's place in one step: an empty or absent target is simply replaced; a target
that holds an earlier run is replaced only with `--overwrite` (else refused before any work), and only
when it holds no file the earlier run did not write (OS metadata such as .DS_Store aside): a run never
deletes a user's files; a target that holds anything else is always refused. A run that fails or is
interrupted leaves the target as it was and its own files (log.txt first) in NAME.failed, except a named
error found before any work (torchrefl.run: no stage completed, nothing written but config.yaml and
log.txt), which leaves nothing (discard). A run killed outright leaves its staging folder, which the next
run into the same target removes.
"""

from __future__ import annotations

import ctypes
import os
import shutil
from pathlib import Path

from torchrefl.core.atomic_files import fsync_dir
from torchrefl.errors import OutputError, RunFolderError
from torchrefl.report.run_marker import CONFIG, LOG, MARKER, read_marker, run_files, unrecorded_files, write_marker

STAGING = ".{name}.staging-{pid}"
FAILED = "{name}.failed"
REPLACED = "-replaced"
RENAME_EXCHANGE = 2
AT_FDCWD = -100
#: files an operating system's file browser leaves in folders: replaced with the run that holds them
OS_METADATA = (".DS_Store", "Thumbs.db", "desktop.ini")


def output_folder(raw: str, option: str = "output.dir") -> Path:
    """The folder named by `raw` with `~` and environment variables expanded, made absolute; OutputError when it
    is empty, names an unset variable, is a file, has a file as an ancestor, or cannot be created or written."""
    if not str(raw).strip():
        raise OutputError(f"{option} is empty: give the folder the run writes (e.g. {option}=outputs/run1)")
    expanded = os.path.expandvars(os.path.expanduser(str(raw)))
    if "$" in expanded:
        raise OutputError(f"{option}={raw!r} names an unset environment variable")
    if expanded.startswith("~"):
        raise OutputError(f"{option}={raw!r}: '~' names no home folder here")
    path = Path(expanded).absolute()
    if path.exists() and not path.is_dir():
        raise OutputError(f"{option}={raw!r}: {path} is a file, expected a folder (or a path to create)")
    ancestor = path.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputError(f"{option}={raw!r}: {ancestor} is a file, so {path} cannot be created")
    if not os.access(ancestor, os.W_OK | os.X_OK) or (path.is_dir() and not os.access(path, os.W_OK | os.X_OK)):
        raise OutputError(f"{option}={raw!r}: no permission to write in {ancestor if not path.is_dir() else path}")
    return path


def holds_a_run(folder: Path) -> bool:
    """Whether `folder` holds a torchrefl run, complete (marker) or not (config.yaml and log.txt)."""
    return (folder / MARKER).is_file() or ((folder / CONFIG).is_file() and (folder / LOG).is_file())


def users_files(folder: Path) -> list[str]:
    """The files in the completed run `folder` that the run did not write, OS metadata (.DS_Store, ._NAME)
    aside; [] for a folder without a readable marker (an incomplete run: which files are whose is unknown)."""
    try:
        marker = read_marker(folder)
    except RunFolderError:
        return []
    own = lambda name: Path(name).name in OS_METADATA or Path(name).name.startswith("._")
    return [name for name in unrecorded_files(folder, marker) if not own(name)]


def pid_alive(pid: int) -> bool:
    """Whether process `pid` exists (on this machine)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _exchange(a: Path, b: Path) -> bool:
    """Swap two existing paths in one step (Linux renameat2 RENAME_EXCHANGE); False where unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    return fn(AT_FDCWD, os.fsencode(a), AT_FDCWD, os.fsencode(b), RENAME_EXCHANGE) == 0


class StagedRunFolder:
    """The staging folder of one run into `target`; `commit()` moves it into place, `abandon()` keeps it as
    NAME.failed. resume_from: an unfinished run into `target` (torchrefl.report.run_resume) whose folder becomes
    this run's staging folder, its files and checkpoints kept."""

    def __init__(self, target: Path, overwrite: bool = False, resume_from: Path | None = None):
        self.target = Path(target)
        self.path = self.target.parent / STAGING.format(name=self.target.name, pid=os.getpid())
        self._remove_stale_staging(keep=resume_from)
        self._check_target(overwrite)
        try:
            if resume_from is not None:
                os.replace(resume_from, self.path)
            else:
                self.path.mkdir(parents=True)
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot create the run's staging folder ({exc.strerror})") from None

    def _check_target(self, overwrite: bool) -> None:
        t = self.target
        if not t.is_dir() or not any(t.iterdir()):
            return
        if not holds_a_run(t):
            sample = sorted(p.name for p in t.iterdir())[:3]
            raise OutputError(
                f"output.dir {t} holds files that are not a torchrefl run (e.g. {sample}); "
                "choose another output.dir (a run never deletes files it did not write)"
            )
        mine = users_files(t) if (t / MARKER).is_file() else []
        if mine:
            raise OutputError(
                f"output.dir {t} holds an earlier run and {len(mine)} file(s) it did not write (e.g. {mine[:3]}); "
                "--overwrite replaces the whole folder and a run never deletes files it did not write: move them "
                "out of the folder first, or choose another output.dir"
            )
        if not overwrite:
            raise OutputError(
                f"output.dir {t} holds an earlier run; give --overwrite to replace it "
                "(it is kept until the new run completes), or choose another output.dir"
            )

    def _remove_stale_staging(self, keep: Path | None = None) -> None:
        """Remove the staging folders of killed runs into the same target (but `keep`, the run to resume); an
        earlier run moved aside by a run killed between its two renames (no atomic swap) is put back."""
        prefix = STAGING.format(name=self.target.name, pid="")
        for p in sorted(self.target.parent.glob(f"{prefix}*")) if self.target.parent.is_dir() else []:
            pid, _, replaced = p.name[len(prefix) :].partition(REPLACED)
            if not pid.isdigit() or pid_alive(int(pid)) or (keep is not None and p == Path(keep)):
                continue
            if replaced == "" and p.name.endswith(REPLACED) and not self.target.exists():
                os.replace(p, self.target)
            else:
                shutil.rmtree(p, ignore_errors=True)

    def commit(self) -> None:
        """Write the marker, then put the staging folder in the target's place (the earlier run removed after)."""
        write_marker(self.path)
        if self.target.is_dir() and any(self.target.iterdir()):
            if not _exchange(self.path, self.target):  # no atomic swap: two renames
                aside = self.path.with_name(self.path.name + REPLACED)
                os.replace(self.target, aside)
                os.replace(self.path, self.target)
                self.path = aside
            shutil.rmtree(self.path)
        else:
            if self.target.is_dir():
                self.target.rmdir()
            os.replace(self.path, self.target)
        fsync_dir(self.target.parent)

    def wrote_nothing(self) -> bool:
        """Whether the staging folder holds nothing but the run's config.yaml and log.txt (no work written)."""
        return set(run_files(self.path)) <= {CONFIG}

    def discard(self) -> None:
        """Remove the staging folder of a run that failed before any work (nothing in it worth keeping)."""
        shutil.rmtree(self.path, ignore_errors=True)

    def abandon(self) -> Path:
        """Keep the failed run's files (its log first) as NAME.failed beside the target; returns that path."""
        failed = self.target.parent / FAILED.format(name=self.target.name)
        if failed.is_dir() and holds_a_run(failed):
            shutil.rmtree(failed, ignore_errors=True)
        if failed.exists():
            return self.path
        os.replace(self.path, failed)
        return failed
