"""Capture plans: the light positions to visit, read from a light-selection result, a plan file or
an explicit list, and ordered to keep the gantry's travel short (nearest neighbour, 2-opt, or-opt).

A mesh_views plan (`kind: mesh_views`, torchrefl.planning.views_selection) lists images, each a camera and a
light; its lights lie on the gantry plane (`gantry`: origin and axes in the world) at gantry_mm [lateral,
vertical], so each image is a Target at that head-frame position naming its camera, light and the plane."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from torchrefl.errors import ConfigError, RigError
from torchrefl.planning.world_candidates import GantryFrame
from torchrefl.rig.model import RigModel


@dataclass
class Target:
    """One image to capture: the light at requested_mm (3,) head frame; grid (i, j) or None. A mesh_views image
    also names its camera and light and the gantry plane in the world (frame); None for a scan."""

    requested_mm: np.ndarray
    grid: tuple | None = None
    camera: str | None = None
    light: str | None = None
    frame: GantryFrame | None = None

    @property
    def key(self) -> tuple:
        """What identifies the image in a capture folder: the position (and the camera of a mesh_views image)."""
        return target_key(self.requested_mm, self.camera)

    def world_mm(self, head_mm) -> np.ndarray:
        """(3,) world position of a head-frame position on this image's gantry plane."""
        return self.frame.world(np.asarray(head_mm, dtype=np.float64)[:2])


def target_key(requested_mm, camera: str | None = None) -> tuple:
    """Target.key of a position (and camera): also how a manifest entry is matched to its target."""
    key = tuple(round(float(v), 3) for v in requested_mm)
    return key if camera is None else key + (camera,)


def targets_from_positions(model: RigModel, positions) -> list[Target]:
    """Targets for head-frame positions (P, 3) or (P, 2) (radial taken from the rig settings)."""
    arr = np.asarray(positions, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] not in (2, 3) or not np.isfinite(arr).all():
        raise RigError(
            f"light positions of shape {arr.shape}: expected (P, 3) [lateral, vertical, radial] "
            f"or (P, 2) [lateral, vertical] finite numbers in mm"
        )
    if arr.shape[1] == 2:
        arr = np.concatenate([arr, np.full((len(arr), 1), model.s.radial_mm)], axis=1)
    return [Target(p.copy(), model.grid_index(p)) for p in arr]


def targets_from_grid(model: RigModel, indices) -> list[Target]:
    """Targets for grid indices [(i, j), ...] (column, row)."""
    out = []
    for ij in indices:
        ij = list(ij)
        if len(ij) != 2:
            raise RigError(f"grid index {ij!r}: expected [column, row]")
        i, j = int(ij[0]), int(ij[1])
        out.append(Target(model.grid_position(i, j), (i, j)))
    return out


def _vector(doc: dict, key: str, n: int, where: str) -> np.ndarray:
    value = doc.get(key) if isinstance(doc, dict) else None
    arr = np.asarray(value, dtype=np.float64) if isinstance(value, list) else None
    if arr is None or arr.shape != (n,) or not np.isfinite(arr).all():
        raise RigError(f"{where}.{key} is {value!r}, expected {n} finite numbers")
    return arr


def targets_from_views_plan(model: RigModel, doc: dict) -> list[Target]:
    """Targets of a mesh_views plan (module doc), in its image order; RigError naming the key at fault, or when
    its lights are not on a gantry plane (a dome or a list: no gantry reaches them)."""
    if doc.get("gantry") is None:
        raise RigError(
            f"a mesh_views plan of layout {doc.get('layout')!r}: its lights are not on a gantry plane; plan with "
            "selection.world.layout: gantry for the rig's gantry to reach them"
        )
    g = doc["gantry"]
    frame = GantryFrame(
        _vector(g, "origin_mm", 3, "gantry"), _vector(g, "lateral", 3, "gantry"), _vector(g, "vertical", 3, "gantry")
    )
    lights = doc.get("lights")
    images = doc.get("images")
    if not isinstance(lights, list) or not isinstance(images, list) or not images:
        raise RigError("a mesh_views plan needs a list 'lights' and a non-empty list 'images'")
    at = {}
    for k, light in enumerate(lights):
        if not isinstance(light, dict) or not isinstance(light.get("name"), str):
            raise RigError(f"lights[{k}] is {light!r}, expected a mapping with a 'name'")
        at[light["name"]] = _vector(light, "gantry_mm", 2, f"lights[{k}]")
    out = []
    for k, image in enumerate(images):
        ok = isinstance(image, dict) and isinstance(image.get("camera"), str) and image.get("camera")
        if not ok or image.get("light") not in at:
            raise RigError(
                f"images[{k}] is {image!r}, expected {{camera: NAME, light: NAME}} naming a light of 'lights'"
            )
        p = np.array([*at[image["light"]], model.s.radial_mm])
        out.append(Target(p, model.grid_index(p), image["camera"], image["light"], frame))
    return out


def load_plan(path, model: RigModel) -> list[Target]:
    """Read a plan: YAML or JSON with `positions_mm: [[lat, vert, rad], ...]` (a light-selection
    result such as outputs/.../selection/selection.json has this key), or `grid: [[i, j], ...]`,
    or a bare list of positions, or a mesh_views plan (`kind: mesh_views`: targets_from_views_plan)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: plan file not found")
    try:
        doc = yaml.safe_load(path.read_text())  # YAML is a superset of JSON
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML/JSON: {exc}") from None
    try:
        if isinstance(doc, list):
            return targets_from_positions(model, doc)
        if isinstance(doc, dict):
            if doc.get("kind") == "mesh_views":
                return targets_from_views_plan(model, doc)
            if doc.get("positions_mm") is not None:
                return targets_from_positions(model, doc["positions_mm"])
            if doc.get("grid") is not None:
                return targets_from_grid(model, doc["grid"])
    except RigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    raise ConfigError(
        f"{path}: expected a list of positions, a mapping with 'positions_mm' or 'grid', or a mesh_views plan"
    )


def unique_targets(targets: list[Target]) -> list[Target]:
    """Drop repeated positions (first occurrence kept)."""
    seen, out = set(), []
    for t in targets:
        if t.key not in seen:
            seen.add(t.key)
            out.append(t)
    return out


def path_length(points: np.ndarray, order, start=None) -> float:
    """Length of the open path visiting points (N, D) in `order`, from `start` (D,) if given."""
    pts = np.asarray(points, dtype=np.float64)[list(order)]
    if start is not None:
        pts = np.concatenate([np.asarray(start, dtype=np.float64)[None], pts])
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


def order_points(points: np.ndarray, start=None) -> list[int]:
    """A short open path through points (N, D) from start (D,) (default: the first point):
    nearest neighbour, then 2-opt segment reversals and or-opt moves (a run of 1-3 points moved
    elsewhere, either way round) until none shortens the path."""
    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    if n <= 1:
        return list(range(n))
    s = pts[0] if start is None else np.asarray(start, dtype=np.float64)
    nodes = np.concatenate([s[None], pts])  # node 0 = fixed start
    d = np.linalg.norm(nodes[:, None] - nodes[None], axis=-1)
    left = set(range(1, n + 1))
    route = [0]
    while left:
        cur = route[-1]
        nxt = min(left, key=lambda k: (d[cur, k], k))
        route.append(nxt)
        left.remove(nxt)
    improved = True
    while improved:
        improved = False
        for i in range(1, n):  # 2-opt: reverse route[i..k]
            for k in range(i + 1, n + 1):
                a, b = route[i - 1], route[i]
                c = route[k]
                after = d[b, route[k + 1]] - d[c, route[k + 1]] if k < n else 0.0
                if d[a, c] - d[a, b] + after < -1e-9:
                    route[i : k + 1] = route[i : k + 1][::-1]
                    improved = True
        for seg in (1, 2, 3):  # or-opt: move a run of 1-3 nodes elsewhere
            i = 1
            while i + seg - 1 <= n:
                run = route[i : i + seg]
                p, q = route[i - 1], (route[i + seg] if i + seg <= n else None)
                gain = d[p, run[0]] + (d[run[-1], q] - d[p, q] if q is not None else 0.0)
                rest = route[:i] + route[i + seg :]
                done = False
                for j in range(1, len(rest) + 1):
                    x, y = rest[j - 1], (rest[j] if j < len(rest) else None)
                    for piece in (run, run[::-1]):
                        cost = d[x, piece[0]] + (d[piece[-1], y] - d[x, y] if y is not None else 0.0)
                        if cost < gain - 1e-9:
                            route = rest[:j] + piece + rest[j:]
                            improved = done = True
                            break
                    if done:
                        break
                i += 1
    return [r - 1 for r in route[1:]]
