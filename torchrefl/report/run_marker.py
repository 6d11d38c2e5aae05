"""The completeness marker of a run folder: written last, it records what the run is and what it wrote.

run_complete.json holds the marker format, the torchrefl version, the SHA-256 of config.yaml and, for every
file of the run (log.txt aside: it is appended to until the process ends), its size and SHA-256. A folder
is a whole run when the marker is there and every file it records is there with the size (and, for those
load_run reads, the hash) it records. Files the marker does not record are not the run's (a user's saved
figure, a .DS_Store): they are left alone and listed (unrecorded_files), never read as the run's.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path

from torchrefl.core.atomic_files import atomic_write_text, fsync_dir, sha256_of
from torchrefl.errors import RunFolderError
from torchrefl.version import __version__

MARKER = "run_complete.json"
MARKER_FORMAT = 1
LOG = "log.txt"
UNRECORDED = (MARKER, LOG)
CONFIG = "config.yaml"


@dataclass(frozen=True)
class RecordedFile:
    size: int
    sha256: str


@dataclass(frozen=True)
class RunMarker:
    format: int
    torchrefl_version: str
    config_sha256: str
    completed_utc: str
    files: dict[str, RecordedFile]


def run_files(folder: Path) -> list[str]:
    """Paths (relative, '/'-separated, sorted) of the files a marker records: all but the marker and log.txt."""
    found = (p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file() or p.is_symlink())
    return sorted(name for name in found if name not in UNRECORDED)


def write_marker(folder) -> RunMarker:
    """Record every file of `folder` and write the marker (atomically, last)."""
    folder = Path(folder)
    files = {name: RecordedFile((folder / name).stat().st_size, sha256_of(folder / name)) for name in run_files(folder)}
    if CONFIG not in files:
        raise RunFolderError(f"{folder / CONFIG}: missing; a run folder's marker records its config")
    marker = RunMarker(
        MARKER_FORMAT,
        __version__,
        files[CONFIG].sha256,
        datetime.now(timezone.utc).isoformat(timespec="seconds"),
        files,
    )
    atomic_write_text(folder / MARKER, json.dumps(asdict(marker), indent=1))
    fsync_dir(folder)
    return marker


def unrecorded_files(folder, marker: RunMarker) -> list[str]:
    """Paths (as run_files) of the files in `folder` that `marker` does not record: not written by the run."""
    return sorted(set(run_files(Path(folder))) - set(marker.files))


def read_marker(folder) -> RunMarker:
    """The marker of `folder` as written (RunFolderError when it is damaged or of another format); no file is
    checked against it (verify_run_folder does)."""
    return _parse_marker(Path(folder) / MARKER)


def _parse_marker(path: Path) -> RunMarker:
    try:
        doc = json.loads(path.read_text())
        files = {str(k): RecordedFile(int(v["size"]), str(v["sha256"])) for k, v in doc["files"].items()}
        marker = RunMarker(
            int(doc["format"]),
            str(doc["torchrefl_version"]),
            str(doc["config_sha256"]),
            str(doc["completed_utc"]),
            files,
        )
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise RunFolderError(
            f"{path}: damaged completeness marker ({type(exc).__name__}: {exc}); the folder cannot be trusted, rerun"
        ) from None
    if marker.format != MARKER_FORMAT:
        raise RunFolderError(f"{path}: marker format {marker.format}, expected {MARKER_FORMAT}")
    return marker


def verify_run_folder(folder, hashed: tuple[str, ...] = ()) -> RunMarker:
    """The marker of a whole run in `folder`; RunFolderError naming what is wrong when the folder has no valid
    marker, lacks a recorded file, or a file's size (or, for `hashed` and config.yaml, its SHA-256) differs
    from the record. Files the marker does not record are not checked (unrecorded_files lists them)."""
    folder = Path(folder)
    path = folder / MARKER
    if not path.is_file():
        raise RunFolderError(
            f"{folder}: no completeness marker {MARKER}: the run is incomplete (failed or killed before it "
            "finished), mixes files of two runs, or was written before run folders had markers; rerun it"
        )
    marker = _parse_marker(path)
    missing = sorted(set(marker.files) - set(run_files(folder)))
    if missing:
        raise RunFolderError(
            f"{folder}: incomplete run: {len(missing)} recorded file(s) missing, e.g. {missing[:3]} ({MARKER})"
        )
    for name, rec in marker.files.items():
        size = (folder / name).stat().st_size
        if size != rec.size:
            raise RunFolderError(
                f"{folder / name}: {size} bytes, the run recorded {rec.size} ({MARKER}): "
                "the file was changed or comes from another run"
            )
    for name in {CONFIG, *hashed} & set(marker.files):
        if sha256_of(folder / name) != marker.files[name].sha256:
            raise RunFolderError(
                f"{folder / name}: content differs from the run's record ({MARKER}): "
                "changed after the run or from another run"
            )
    if marker.config_sha256 != marker.files.get(CONFIG, RecordedFile(0, "")).sha256:
        raise RunFolderError(f"{path}: config_sha256 does not match the recorded {CONFIG}")
    return marker
