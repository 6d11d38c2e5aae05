"""The error family of torchrefl.

Every bad input raises a TorchReflError subclass whose message names the file,
the key or the field and what was expected. Callers (the CLI) print the message
without a traceback (command_status); library users can catch TorchReflError.
"""

import sys
from typing import Callable


class TorchReflError(Exception):
    """Base class of every error torchrefl raises on bad input or bad state."""


class ConfigError(TorchReflError):
    """A configuration file, key or value is missing, unknown or out of range."""


class CaptureError(TorchReflError):
    """Capture data (images, light tables, masks, normals) is missing or inconsistent."""


class DataMissingError(CaptureError):
    """The capture folder that capture.path names does not exist; the message says how to get the data."""


class MissingPackageError(TorchReflError):
    """An optional package that this input or output needs is not installed; the message names the file and the
    install command."""


class GeometryError(TorchReflError):
    """Geometry (range image, mesh, normals) is unusable: NaN, non-unit, degenerate."""


class FitError(TorchReflError):
    """The fit cannot proceed (nothing to fit, diverged)."""


class MemoryLimitError(TorchReflError):
    """A run would need more memory than the machine has free; the message names the setting that brings it down."""


class RigError(TorchReflError):
    """The capture rig (serial port, GRBL controller, camera) failed or refused a command."""


class OutputError(TorchReflError):
    """The output folder cannot hold a run: empty path, a file, a file as parent, not writable, another run."""


class RunFolderError(TorchReflError):
    """A run folder is incomplete, mixes two runs or holds damaged files (load_run)."""


def command_status(work: Callable[[], int]) -> int:
    """The exit status of a command's work: its own; 2 for a TorchReflError (printed on one line to stderr, no
    traceback); 130 when interrupted."""
    try:
        return work()
    except TorchReflError as exc:
        _print_error(f"error: {exc}", exc)
        return 2
    except KeyboardInterrupt as exc:
        _print_error("interrupted", exc)
        return 130


def _print_error(text: str, exc: BaseException) -> None:
    """An error on stderr, once: the message, then the notes a run added to the exception (where its files are)."""
    print(f"torchrefl: {text}", file=sys.stderr)
    for note in getattr(exc, "__notes__", ()):
        print(f"  {note}", file=sys.stderr)
