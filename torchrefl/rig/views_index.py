"""The mesh_views index of a rig capture folder: images.json pairing each recorded image with its camera and light,
and lights.json with the lights' world positions, both derived from manifest.jsonl (so they are rewritten whole
after every image and after a resume, and never disagree with the recorded images).

A light's position is the mean of the world positions reached for its images (each within position_tolerance_mm
of the plan's); its intensity is the rig's light.intensity. The cameras (cameras.json) and the mesh are the user's
(the plan was made with them): the folder loads with the mesh_views loader once they are beside the images.
"""

from __future__ import annotations

import json

import numpy as np

from torchrefl.capture.cameras_json import CAMERAS_JSON
from torchrefl.capture.images_json import IMAGES_JSON
from torchrefl.capture.lights_json import LIGHTS_JSON
from torchrefl.core.atomic_files import atomic_write_text


def write_views_index(root, entries: list[dict], intensity, encoding: str) -> None:
    """Write root/images.json and root/lights.json for the manifest entries that name a camera (module doc)."""
    mine = [e for e in entries if e.get("camera") is not None]
    reached: dict[str, list] = {}
    for e in mine:
        reached.setdefault(e["light"], []).append(e["light_mm"])
    lights = {
        name: {
            "position": [float(v) for v in np.mean(np.asarray(at, dtype=np.float64), axis=0)],
            "intensity": [float(v) for v in intensity],
        }
        for name, at in reached.items()
    }
    images = {
        "encoding": encoding,
        "cameras": CAMERAS_JSON,
        "images": [{"file": e["image"], "camera": e["camera"], "light": e["light"]} for e in mine],
    }
    atomic_write_text(root / LIGHTS_JSON, json.dumps(lights, indent=2) + "\n")
    atomic_write_text(root / IMAGES_JSON, json.dumps(images, indent=2) + "\n")
