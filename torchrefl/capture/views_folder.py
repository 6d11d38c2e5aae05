"""The metadata of a `mesh_views` capture folder: scene.yaml, cameras.json, lights.json, images.json.

`read_views_folder(folder)` is the one place the mesh_views loader reads metadata from (the camera readers and
their projection are to be the `cameras` branch's torchrefl.capture.cameras; this module is their stand-in with the
same interface: Cameras.project(points, camera) -> Projection(uv, depth), centres(), width, height, names, index).

Conventions (docs/capture-formats.md, `mesh_views`): cameras in the OpenCV convention, X_cam = R X_world + t, +z
forward, y down, u = fx x'' + cx with OpenCV's radial-tangential distortion (k1, k2, p1, p2, k3) of the normalised
coordinates, the centre of the top-left pixel at (0, 0); lights: point lights (`position`, world frame) or
directional lights (`direction` towards the light), RGB radiant `intensity`; images: `file`, `camera`, `light`,
optional `exposure` (default 1) and `mask`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch
import yaml

from torchrefl.errors import CaptureError

DISTORTION = ("k1", "k2", "p1", "p2", "k3")
ENCODINGS = ("linear", "linear16", "srgb")


@dataclass(frozen=True)
class Projection:
    """uv: (N, 2) pixel coordinates (centre of the top-left pixel at (0, 0)); depth: (N,) camera-frame z."""

    uv: torch.Tensor
    depth: torch.Tensor


@dataclass
class Cameras:
    """N cameras: names, width, height (N,) int64, K (N, 3, 3), distortion (N, 5), R (N, 3, 3), t (N, 3), float64."""

    names: tuple
    width: torch.Tensor
    height: torch.Tensor
    K: torch.Tensor
    distortion: torch.Tensor
    R: torch.Tensor
    t: torch.Tensor
    source: str = "<memory>"

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def centres(self) -> torch.Tensor:
        """(N, 3) camera centres in the world frame, -R^T t."""
        return -torch.einsum("nji,nj->ni", self.R, self.t)

    def project(self, points: torch.Tensor, camera: int) -> Projection:
        """Pixel coordinates and depth of world points (M, 3) in camera `camera` (NaN uv behind the camera)."""
        X = points.double() @ self.R[camera].T + self.t[camera]
        z = X[:, 2]
        x, y = X[:, 0] / z, X[:, 1] / z
        k1, k2, p1, p2, k3 = self.distortion[camera]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        K = self.K[camera]
        uv = torch.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], -1)
        uv[z <= 0] = float("nan")
        return Projection(uv, z)


@dataclass
class ViewLight:
    """A light: name, kind ('point' or 'directional'), position (point) or unit direction towards the light
    (directional) (3,), RGB radiant intensity (3,)."""

    name: str
    kind: str
    vector: np.ndarray
    intensity: np.ndarray


@dataclass
class ViewImage:
    """One photograph: file (relative to the folder), camera and light names, exposure factor, mask file or None."""

    file: str
    camera: str
    light: str
    exposure: float = 1.0
    mask: Optional[str] = None


@dataclass
class ViewsFolder:
    """A mesh_views folder's metadata (module doc)."""

    folder: Path
    units: str
    cameras: Cameras
    lights: list[ViewLight]
    images: list[ViewImage]
    encoding: str
    saturation_level: Optional[float]
    kappa: Optional[list]


def _json(path: Path) -> dict:
    if not path.is_file():
        raise CaptureError(f"{path}: not found (a mesh_views folder holds cameras.json, lights.json and images.json)")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CaptureError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise CaptureError(f"{path}: expected a JSON object at the top, got {type(doc).__name__}")
    return doc


def _entries(doc: dict, key: str, path: Path) -> list:
    entries = doc.get(key)
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise CaptureError(f"{path}: key '{key}' must be a non-empty list of objects")
    return entries


def _number(entry: dict, key: str, where: str, default=None, positive: bool = False) -> float:
    value = entry.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CaptureError(f"{where}: key '{key}' is {value!r}, expected a finite number")
    if positive and value <= 0:
        raise CaptureError(f"{where}: key '{key}' is {value!r}, expected a number > 0")
    return float(value)


def _array(entry: dict, key: str, shape: tuple, where: str) -> np.ndarray:
    try:
        a = np.asarray(entry[key], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise CaptureError(f"{where}: key '{key}' missing or not numbers (expected shape {shape})") from None
    if a.shape != shape and not (shape == (3,) and a.shape == ()):
        raise CaptureError(f"{where}: key '{key}' has shape {a.shape}, expected {shape}")
    if not np.isfinite(a).all():
        raise CaptureError(f"{where}: key '{key}' has NaN or inf values")
    return np.broadcast_to(a, shape).copy()


def read_cameras(path: Path) -> Cameras:
    """cameras.json: {"cameras": [{name, width, height, fx, fy, cx, cy, [k1 k2 p1 p2 k3], R, t}, ...]}."""
    entries = _entries(_json(path), "cameras", path)
    names, rows = [], []
    for i, e in enumerate(entries):
        where = f"{path}: cameras[{i}]"
        name = e.get("name")
        if not isinstance(name, str) or not name or name in names:
            raise CaptureError(f"{where}: key 'name' is {name!r}, expected a unique non-empty string")
        size = [e.get(k) for k in ("width", "height")]
        if not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size):
            raise CaptureError(f"{where}: width and height are {size}, expected positive integers (pixels)")
        f = [_number(e, k, where, positive=True) for k in ("fx", "fy")]
        c = [_number(e, k, where) for k in ("cx", "cy")]
        dist = [_number(e, k, where, default=0.0) for k in DISTORTION]
        R, t = _array(e, "R", (3, 3), where), _array(e, "t", (3,), where)
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) <= 0:
            raise CaptureError(f"{where}: key 'R' is not a rotation (orthonormal, det +1)")
        names.append(name)
        rows.append((size, f, c, dist, R, t))
    t64 = lambda x: torch.as_tensor(np.asarray(x, dtype=np.float64))  # noqa: E731
    K = torch.zeros(len(rows), 3, 3, dtype=torch.float64)
    for i, (_, f, c, _, _, _) in enumerate(rows):
        K[i] = t64([[f[0], 0, c[0]], [0, f[1], c[1]], [0, 0, 1]])
    return Cameras(
        names=tuple(names),
        width=torch.tensor([r[0][0] for r in rows]),
        height=torch.tensor([r[0][1] for r in rows]),
        K=K,
        distortion=t64([r[3] for r in rows]),
        R=t64([r[4] for r in rows]),
        t=t64([r[5] for r in rows]),
        source=str(path),
    )


def read_lights(path: Path) -> list[ViewLight]:
    """lights.json: {"lights": [{name, type: point, position, intensity} | {name, type: directional, direction,
    intensity}, ...]}."""
    lights = []
    for i, e in enumerate(_entries(_json(path), "lights", path)):
        where = f"{path}: lights[{i}]"
        kind = e.get("type", "point")
        if kind not in ("point", "directional"):
            raise CaptureError(f"{where}: key 'type' is {kind!r}, expected 'point' or 'directional'")
        vector = _array(e, "position" if kind == "point" else "direction", (3,), where)
        if kind == "directional":
            vector = vector / max(np.linalg.norm(vector), 1e-300)
        intensity = _array(e, "intensity", (3,), where)
        if (intensity <= 0).any():
            raise CaptureError(f"{where}: key 'intensity' is {intensity.tolist()}, expected values > 0")
        name = e.get("name")
        if not isinstance(name, str) or not name or name in [light.name for light in lights]:
            raise CaptureError(f"{where}: key 'name' is {name!r}, expected a unique non-empty string")
        lights.append(ViewLight(name, kind, vector, intensity))
    return lights


def read_views_folder(folder) -> ViewsFolder:
    """The folder's metadata; CaptureError naming the file and key for anything missing or malformed, and for an
    image entry naming a camera or light that the folder does not have or a file that is not there."""
    folder = Path(folder)
    units = "mm"
    if (folder / "scene.yaml").is_file():
        scene = yaml.safe_load((folder / "scene.yaml").read_text()) or {}
        units = scene.get("units", "mm") if isinstance(scene, dict) else units
    cameras = read_cameras(folder / "cameras.json")
    lights = read_lights(folder / "lights.json")
    path = folder / "images.json"
    doc = _json(path)
    encoding = doc.get("encoding", "linear")
    if encoding not in ENCODINGS:
        raise CaptureError(f"{path}: key 'encoding' is {encoding!r}, expected one of {', '.join(ENCODINGS)}")
    saturation = _number(doc, "saturation_level", str(path)) if "saturation_level" in doc else None
    kappa = _array(doc, "kappa", (3,), str(path)).tolist() if "kappa" in doc else None
    light_names = [light.name for light in lights]
    images = []
    for i, e in enumerate(_entries(doc, "images", path)):
        where = f"{path}: images[{i}]"
        for key, known, what in (("camera", cameras.names, "cameras.json"), ("light", light_names, "lights.json")):
            if e.get(key) not in known:
                raise CaptureError(
                    f"{where}: key '{key}' names {e.get(key)!r}, which {what} does not have ({', '.join(known[:5])}"
                    f"{', ...' if len(known) > 5 else ''})"
                )
        for key in ("file", "mask"):
            if key in e and not (isinstance(e[key], str) and (folder / e[key]).is_file()):
                raise CaptureError(f"{where}: key '{key}' names {e[key]!r}, which is not a file in {folder}")
        if "file" not in e:
            raise CaptureError(f"{where}: key 'file' missing (the image file, relative to the folder)")
        exposure = _number(e, "exposure", where, default=1.0, positive=True)
        images.append(ViewImage(e["file"], e["camera"], e["light"], exposure, e.get("mask")))
    return ViewsFolder(folder, units, cameras, lights, images, encoding, saturation, kappa)
