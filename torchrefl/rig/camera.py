"""Camera triggers: `capture(path, position_mm)` writes one image file at `path`.

ExternalCommandCamera runs a command template (gphoto2, a scanner's texture export, ...);
SimulatedCamera renders an image for the light position actually reached (a dry run).
"""

from __future__ import annotations

import shlex
import subprocess
from pathlib import Path
from typing import Callable

import numpy as np

from torchrefl.errors import CaptureError, RigError


class Camera:
    """Interface: write one image for the light at head-frame position_mm (3,) [lateral, vertical, radial]; for a
    mesh_views plan, the light's world position (3,) mm and the name of the camera to trigger."""

    def capture(self, path, position_mm=None, camera: str | None = None) -> None:
        raise NotImplementedError

    def check_cameras(self, names) -> None:
        """RigError when this trigger cannot tell apart the cameras a plan names (default: it can)."""


class ExternalCommandCamera(Camera):
    """Runs `template` with {path} replaced by the (quoted) output file and {camera} by the camera a mesh_views
    plan names for the image, e.g. `gphoto2 --capture-image-and-download --force-overwrite --filename {path}`. The
    command must write that file; a non-zero exit, a timeout or a missing/empty file raise RigError."""

    def __init__(self, template: str, timeout_s: float = 120.0):
        if "{path}" not in template:
            raise RigError(f"camera command {template!r} has no {{path}} placeholder for the image file")
        self.template = template
        self.timeout_s = float(timeout_s)

    def check_cameras(self, names) -> None:
        names = sorted(set(names))
        if len(names) > 1 and "{camera}" not in self.template:
            raise RigError(
                f"camera command {self.template!r} has no {{camera}} placeholder, but the plan names "
                f"{len(names)} cameras ({', '.join(names[:4])}{', ...' if len(names) > 4 else ''}): the command "
                "must trigger the camera it is given"
            )

    def capture(self, path, position_mm=None, camera: str | None = None) -> None:
        path = Path(path)
        text = self.template.replace("{path}", shlex.quote(str(path)))
        argv = shlex.split(text.replace("{camera}", shlex.quote(camera or "")))
        try:
            proc = subprocess.run(argv, capture_output=True, timeout=self.timeout_s)
        except FileNotFoundError:
            raise RigError(f"camera command {argv[0]!r} not found (camera.command = {self.template!r})") from None
        except subprocess.TimeoutExpired:
            raise RigError(f"camera command {self.template!r} did not finish within {self.timeout_s:.1f} s") from None
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).decode("utf-8", "replace").strip()[-300:]
            raise RigError(f"camera command {' '.join(argv)!r} exited with status {proc.returncode}: {tail}")
        if not path.is_file() or path.stat().st_size == 0:
            raise RigError(f"camera command {' '.join(argv)!r} succeeded but wrote no image at {path}")


class SimulatedCamera(Camera):
    """render(position_mm (3,) float64) -> (H, W, 3) uint8 or uint16 image, written as an 8- or
    16-bit PNG; render(position_mm, camera) for a mesh_views plan's images; calls counts the captures."""

    def __init__(self, render: Callable[[np.ndarray], np.ndarray]):
        self.render = render
        self.calls = 0

    def capture(self, path, position_mm=None, camera: str | None = None) -> None:
        from torchrefl.capture.images import write_png

        if position_mm is None:
            raise RigError("SimulatedCamera.capture needs the light position (position_mm) to render an image")
        where = np.asarray(position_mm, dtype=np.float64)
        img = np.asarray(self.render(where) if camera is None else self.render(where, camera))
        bits = 16 if img.dtype == np.uint16 else 8
        try:
            write_png(path, img, bits=bits)
        except CaptureError as exc:
            raise RigError(f"simulated camera: {exc}") from None
        self.calls += 1
