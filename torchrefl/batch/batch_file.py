"""The batch file: which captures one batch fits, from which config, into which folders.

base: configs/default.yaml          # the config every capture starts from (a file, relative to this file, or
                                    # a bundled name)
captures:                           # capture folders or globs (relative to this file); kind detected from the
  - scans/*                         # folder's contents unless given
  - {path: ps/ball, kind: photometric_stereo, overrides: [fit.model=local]}
synthetic_seeds: [1, 2, 3]          # base's synthetic scene rendered with seed set to each
overrides: [fit.iterations=40]      # dotted keys for every capture, as on the train command line
output: batch_out                   # the root: one sub-folder per capture (relative to this file)
cpus_per_task: 1                    # CPUs Ray reserves for each fit (torch and Embree use as many threads)
gpus_per_task: 0                    # GPUs Ray reserves for each fit (set device: cuda in overrides to use it)
retries: 2                          # times Ray reruns a fit whose worker process died
"""

from __future__ import annotations

import glob
import math
from dataclasses import dataclass
from pathlib import Path

from torchrefl.config_loading import read_yaml_mapping
from torchrefl.errors import ConfigError

KEYS = ("base", "captures", "synthetic_seeds", "overrides", "output", "cpus_per_task", "gpus_per_task", "retries")
CAPTURE_KEYS = ("path", "kind", "overrides")
#: the file that tells each capture kind's folder (docs/capture-formats.md), in the order they are looked for
KIND_FILES = {"scan.yaml": "cylindrical_scan", "scene.yaml": "mesh_views", "light_directions.txt": "photometric_stereo"}


@dataclass(frozen=True)
class BatchTask:
    """One fit of a batch: its name (its output sub-folder's), the train overrides, its output folder and, for a
    capture folder, the folder and its kind (None: detected when the task runs, so a folder that tells no kind
    fails that task alone)."""

    name: str
    overrides: tuple[str, ...]
    output: Path
    capture: Path | None = None
    kind: str | None = None

    def train_overrides(self) -> list[str]:
        """The dotted overrides of this fit: capture.path and capture.kind (detected), the batch's and its own,
        output.dir."""
        capture = [] if self.capture is None else [f"capture.path={self.capture}"]
        if self.capture is not None:
            capture.append(f"capture.kind={self.kind or detect_kind(self.capture)}")
        return [*capture, *self.overrides, f"output.dir={self.output}"]


@dataclass(frozen=True)
class BatchFile:
    """A read batch file: the base config, the tasks, the output root and what each task asks of Ray."""

    path: Path
    base: str
    tasks: tuple[BatchTask, ...]
    output: Path
    cpus_per_task: float
    gpus_per_task: float
    retries: int


def detect_kind(folder: Path) -> str:
    """The capture kind of `folder` from the file that tells it (KIND_FILES); ConfigError when none is there."""
    for name, kind in KIND_FILES.items():
        if (folder / name).is_file():
            return kind
    raise ConfigError(
        f"captures: cannot tell the capture kind of {folder}: it holds none of {', '.join(KIND_FILES)}; "
        "name it in the batch file ({path: ..., kind: ...})"
    )


def _list(doc: dict, key: str, where: str) -> list:
    value = doc.get(key) or []
    if not isinstance(value, list):
        raise ConfigError(f"{where}: '{key}' must be a list, got {type(value).__name__}")
    return value


def _overrides(value, where: str) -> tuple[str, ...]:
    if isinstance(value, dict):
        return tuple(f"{k}={v}" for k, v in value.items())
    if not isinstance(value, list) or not all(isinstance(v, str) and "=" in v for v in value):
        raise ConfigError(f"{where}: overrides must be a list of dotted.key=value strings or a mapping")
    return tuple(value)


def _captures(entry, root: Path, where: str) -> list[tuple[Path, str | None, tuple[str, ...]]]:
    """(folder, kind or None, overrides) of one `captures` entry (a glob gives one per matching folder)."""
    if isinstance(entry, str):
        entry = {"path": entry}
    if not isinstance(entry, dict) or "path" not in entry or set(entry) - set(CAPTURE_KEYS):
        raise ConfigError(f"{where}: a capture is a path (or glob) or a mapping with keys {', '.join(CAPTURE_KEYS)}")
    pattern = str(root / str(entry["path"]))
    found = sorted(Path(p) for p in glob.glob(pattern)) if glob.has_magic(pattern) else [Path(pattern)]
    if not found:
        raise ConfigError(f"{where}: '{entry['path']}' matches no folder")
    extra = _overrides(entry.get("overrides", []), where)
    return [(folder.absolute(), entry.get("kind"), extra) for folder in found]


def _unique(name: str, taken: set[str]) -> str:
    out, i = name, 2
    while out in taken:
        out, i = f"{name}-{i}", i + 1
    taken.add(out)
    return out


def read_batch(path) -> BatchFile:
    """The batch file at `path` (ConfigError naming the file and key when a key is unknown or malformed)."""
    path = Path(path)
    doc = read_yaml_mapping(path, ConfigError, "batch file")
    where = str(path)
    unknown = sorted(set(doc) - set(KEYS))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; a batch file has {', '.join(KEYS)}")
    for key in ("base", "output"):
        if not isinstance(doc.get(key), str) or not doc[key].strip():
            raise ConfigError(f"{where}: '{key}' is missing: give {'the base config' if key == 'base' else 'the root'}")
    root = path.absolute().parent
    base = str(root / doc["base"]) if (root / doc["base"]).is_file() else doc["base"]
    output = (root / doc["output"]).absolute()
    common = _overrides(doc.get("overrides", []), f"{where}: overrides")
    tasks, taken = [], set()
    for entry in _list(doc, "captures", where):
        for folder, kind, extra in _captures(entry, root, f"{where}: captures"):
            name = _unique(folder.name, taken)
            tasks.append(BatchTask(name, (*common, *extra), output / name, folder, kind))
    for seed in _list(doc, "synthetic_seeds", where):
        if not isinstance(seed, int) or isinstance(seed, bool):
            raise ConfigError(f"{where}: synthetic_seeds must be integers, got {seed!r}")
        name = _unique(f"seed-{seed}", taken)
        tasks.append(BatchTask(name, (*common, f"seed={seed}"), output / name))
    if not tasks:
        raise ConfigError(f"{where}: no captures and no synthetic_seeds: nothing to fit")
    cpus, gpus, retries = doc.get("cpus_per_task", 1), doc.get("gpus_per_task", 0), doc.get("retries", 2)
    if not isinstance(cpus, (int, float)) or cpus <= 0 or not isinstance(gpus, (int, float)) or gpus < 0:
        raise ConfigError(f"{where}: cpus_per_task must be > 0 and gpus_per_task >= 0 (numbers)")
    if not isinstance(retries, int) or retries < 0:
        raise ConfigError(f"{where}: retries must be an integer >= 0")
    return BatchFile(path, base, tuple(tasks), output, float(cpus), float(gpus), retries)


def task_threads(batch: BatchFile) -> int:
    """torch and Embree threads per fit: the CPUs Ray reserves for it (at least 1), so fits do not fight over cores."""
    return max(1, math.floor(batch.cpus_per_task))
