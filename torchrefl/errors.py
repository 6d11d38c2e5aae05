"""The error family of torchrefl.

Every bad input raises a TorchReflError subclass whose message names the file,
the key or the field and what was expected. Callers (the CLI) print the message
without a traceback; library users can catch TorchReflError.
"""


class TorchReflError(Exception):
    """Base class of every error torchrefl raises on bad input or bad state."""


class ConfigError(TorchReflError):
    """A configuration file, key or value is missing, unknown or out of range."""


class CaptureError(TorchReflError):
    """Capture data (images, light tables, masks, normals) is missing or inconsistent."""


class DataMissingError(CaptureError):
    """The capture folder that capture.path names does not exist; the message says how to get the data."""


class GeometryError(TorchReflError):
    """Geometry (range image, mesh, normals) is unusable: NaN, non-unit, degenerate."""


class FitError(TorchReflError):
    """The fit cannot proceed (nothing to fit, diverged)."""


class RigError(TorchReflError):
    """The capture rig (serial port, GRBL controller, camera) failed or refused a command."""


class OutputError(TorchReflError):
    """The output folder cannot hold a run: empty path, a file, a file as parent, not writable, another run."""


class RunFolderError(TorchReflError):
    """A run folder is incomplete, mixes two runs or holds damaged files (load_run)."""
