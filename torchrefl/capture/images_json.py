"""images.json of a mesh_views folder: the photographs, each with its camera and its light, read strictly.

    {"encoding": "linear", "saturation_level": 0.995, "kappa": [3.14159, 3.14159, 3.14159],
     "cameras": "cameras.json",
     "images": [{"file": "images/cam0_led0.png", "camera": "cam0", "light": "led0"},
                {"file": "images/cam0_led1.png", "camera": "cam0", "light": "led1", "exposure": 2.0,
                 "mask": "masks/cam0.png"}]}

Only the document's shape is checked here; that the names and files exist is view_folder's job.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from torchrefl.capture import json_fields as jf
from torchrefl.capture.cameras_json import CAMERAS_JSON
from torchrefl.errors import CaptureError

IMAGES_JSON = "images.json"
KEYS = ("encoding", "saturation_level", "kappa", "cameras", "images")
IMAGE_KEYS = ("file", "camera", "light", "exposure", "mask")
#: linear: samples are linear fractions of full range (8- or 16-bit PNG, OpenEXR); srgb: 8-bit samples decoded by the
#: sRGB curve
ENCODINGS = ("linear", "srgb")


@dataclass(frozen=True)
class ViewImage:
    """One photograph: `file` (relative to the folder), the names of its camera and light, its exposure factor
    (pixel = exposure x kappa x radiance, so values are divided by it) and an optional mask file (pixels where
    every channel is zero are left out)."""

    file: str
    camera: str
    light: str
    exposure: float = 1.0
    mask: Optional[str] = None


@dataclass(frozen=True)
class ViewList:
    """images.json: the images, their encoding, the folder's saturation level and kappa (None: the config's)
    and where the cameras are (a .json file, or a folder holding a COLMAP model), relative to the folder."""

    images: tuple[ViewImage, ...]
    encoding: str
    saturation_level: Optional[float]
    kappa: Optional[np.ndarray]
    cameras: str
    source: str


def _image(entry, where: str, key: str) -> ViewImage:
    jf.mapping(entry, where, key)
    jf.refuse_unknown(entry, IMAGE_KEYS, where, key)
    names = {k: jf.text(jf.need(entry, k, where, key), where, f"{key}.{k}") for k in ("file", "camera", "light")}
    exposure = jf.number(entry.get("exposure", 1.0), where, f"{key}.exposure", positive=True)
    mask = jf.text(entry["mask"], where, f"{key}.mask") if "mask" in entry else None
    return ViewImage(exposure=exposure, mask=mask, **names)


def read_images_json(path) -> ViewList:
    """The images.json document; CaptureError naming the file and the key for anything malformed."""
    path = Path(path)
    where = str(path)
    doc = jf.mapping(jf.read_json(path, "a JSON object with 'encoding' and 'images'"), where, "the document")
    jf.refuse_unknown(doc, KEYS, where, "")
    encoding = jf.need(doc, "encoding", where, "")
    if encoding not in ENCODINGS:
        raise CaptureError(f"{where}: .encoding is {encoding!r}, expected one of {', '.join(ENCODINGS)}")
    saturation = None
    if "saturation_level" in doc:
        saturation = jf.number(doc["saturation_level"], where, ".saturation_level")
        if not 0.0 < saturation <= 1.0:
            raise CaptureError(f"{where}: .saturation_level = {saturation!r}, expected a fraction in (0, 1]")
    kappa = jf.rgb(doc["kappa"], where, ".kappa") if "kappa" in doc else None
    entries = jf.need(doc, "images", where, "")
    if not isinstance(entries, list) or not entries:
        raise CaptureError(f"{where}: .images must be a non-empty list of images, got {entries!r}")
    return ViewList(
        images=tuple(_image(entry, where, f".images[{i}]") for i, entry in enumerate(entries)),
        encoding=encoding,
        saturation_level=saturation,
        kappa=kappa,
        cameras=jf.text(doc.get("cameras", CAMERAS_JSON), where, ".cameras"),
        source=where,
    )
