"""lights.json of a mesh_views folder: one JSON object, light name -> light, read strictly into Lights.

    {"led0": {"position": [120.0, -80.0, 300.0], "intensity": [60000, 58000, 61000]},
     "sun":  {"direction": [0.0, -0.6, 0.8], "intensity": 0.5}}

A point light has `position` (world frame, the world unit): a texel at distance d with n.l > 0 receives the
irradiance Y n.l / d^2, Y = `intensity` in sensor full range x (world unit)^2 (the other kinds' units, so
with kappa = pi a white Lambertian texel facing it reads Y / d^2). A directional light has `direction` (a unit
vector towards the light, world frame, within DIRECTION_TOLERANCE; renormalised): irradiance Y n.l, Y in
sensor full range. `intensity` is 3 numbers > 0 (RGB) or one number for all three channels.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from torchrefl.capture import json_fields as jf
from torchrefl.errors import CaptureError

LIGHTS_JSON = "lights.json"
KEYS = ("position", "direction", "intensity")
#: largest |1 - |direction|| accepted (directions written with 3 decimals are inside)
DIRECTION_TOLERANCE = 1e-2


@dataclass(frozen=True)
class Lights:
    """L lights (float64 arrays).

    names: L distinct names (lights.json's keys).
    point: (L,) bool, True for a point light, False for a directional one.
    position: (L, 3) world position of point lights (world unit); NaN for directional lights.
    direction: (L, 3) unit vector towards directional lights; NaN for point lights.
    intensity: (L, 3) RGB radiant intensity Y (point: sensor full range x unit^2; directional: full range).
    source: the file the lights came from.
    """

    names: tuple[str, ...]
    point: np.ndarray
    position: np.ndarray
    direction: np.ndarray
    intensity: np.ndarray
    source: str = "<memory>"

    def __len__(self) -> int:
        return len(self.names)

    def scaled(self, factor: float) -> "Lights":
        """The same lights in a world unit `factor` times smaller (e.g. a mesh's unit to mm): positions x factor,
        point intensities x factor^2 (so Y / d^2 is unchanged); directional lights unchanged."""
        gain = np.where(self.point, factor**2, 1.0)[:, None]
        return replace(self, position=self.position * factor, intensity=self.intensity * gain)

    def index(self, name: str) -> int:
        return self.names.index(name)


def _direction(value, where: str, key: str) -> np.ndarray:
    d = jf.array(value, (3,), where, key)
    norm = float(np.linalg.norm(d))
    if abs(norm - 1.0) > DIRECTION_TOLERANCE:
        raise CaptureError(
            f"{where}: {key} has length {norm:.4g}, expected a unit vector towards the light (+- {DIRECTION_TOLERANCE})"
        )
    return d / norm


def read_lights_json(path) -> Lights:
    """The lights of a lights.json file; CaptureError naming the file and the key for anything malformed."""
    path = Path(path)
    where = str(path)
    doc = jf.mapping(jf.read_json(path, "a JSON object: light name -> light"), where, "the document")
    if not doc:
        raise CaptureError(f"{where}: no light (expected a JSON object: light name -> light)")
    nan = np.full(3, np.nan)
    point, position, direction, intensity = [], [], [], []
    for name, light in doc.items():
        key = f"[{name!r}]"
        jf.mapping(light, where, key)
        jf.refuse_unknown(light, KEYS, where, key)
        if ("position" in light) == ("direction" in light):
            raise CaptureError(
                f"{where}: light {key} needs exactly one of 'position' (a point light) and 'direction' "
                f"(a directional light), got keys {sorted(light)}"
            )
        is_point = "position" in light
        point.append(is_point)
        position.append(jf.array(light["position"], (3,), where, f"{key}.position") if is_point else nan)
        direction.append(nan if is_point else _direction(light["direction"], where, f"{key}.direction"))
        intensity.append(jf.rgb(jf.need(light, "intensity", where, key), where, f"{key}.intensity"))
    return Lights(
        names=tuple(doc),
        point=np.array(point, dtype=bool),
        position=np.array(position),
        direction=np.array(direction),
        intensity=np.array(intensity),
        source=where,
    )
