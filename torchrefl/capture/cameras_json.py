"""cameras.json of a mesh_views folder: one JSON object, camera name -> camera, read strictly into Cameras.

    {"cam0": {"width": 1600, "height": 1200, "fx": 2000.0, "fy": 2000.0, "cx": 799.5, "cy": 599.5,
              "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0,
              "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0.0, 0.0, 500.0]}}

OpenCV convention (torchrefl/capture/cameras.py): X_cam = R X_world + t, the centre of the top-left pixel at
(0, 0). The distortion coefficients are optional (0 when absent); every other key is required, and an unknown
key is an error naming the camera and the key.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from torchrefl.capture import json_fields as jf
from torchrefl.capture.cameras import DISTORTION, Cameras
from torchrefl.errors import CaptureError

CAMERAS_JSON = "cameras.json"
REQUIRED = ("width", "height", "fx", "fy", "cx", "cy", "R", "t")
KEYS = REQUIRED + DISTORTION


def read_cameras_json(path) -> Cameras:
    """The cameras of a cameras.json file; CaptureError naming the file and the key for anything malformed,
    and (Cameras.validate) for a non-positive focal length or a non-orthonormal R."""
    path = Path(path)
    where = str(path)
    doc = jf.mapping(jf.read_json(path, "a JSON object: camera name -> camera"), where, "the document")
    if not doc:
        raise CaptureError(f"{where}: no camera (expected a JSON object: camera name -> camera)")
    columns: dict[str, list] = {key: [] for key in KEYS}
    for name, cam in doc.items():
        key = f"[{name!r}]"
        jf.mapping(cam, where, key)
        jf.refuse_unknown(cam, KEYS, where, key)
        for field in ("width", "height"):
            columns[field].append(jf.integer(jf.need(cam, field, where, key), where, f"{key}.{field}"))
        for field in ("fx", "fy", "cx", "cy"):
            columns[field].append(jf.number(jf.need(cam, field, where, key), where, f"{key}.{field}"))
        for field in DISTORTION:
            columns[field].append(jf.number(cam.get(field, 0.0), where, f"{key}.{field}"))
        columns["R"].append(jf.array(jf.need(cam, "R", where, key), (3, 3), where, f"{key}.R"))
        columns["t"].append(jf.array(jf.need(cam, "t", where, key), (3,), where, f"{key}.t"))
    return Cameras.from_arrays(
        list(doc),
        columns["width"],
        columns["height"],
        columns["fx"],
        columns["fy"],
        columns["cx"],
        columns["cy"],
        np.array([columns[k] for k in DISTORTION]).T,
        np.array(columns["R"]),
        np.array(columns["t"]),
        source=where,
    )
