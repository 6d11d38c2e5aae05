"""scan.yaml of a cylindrical_scan folder (and the rig's manifest.jsonl), read strictly.

Every key is known: those the synthetic scanner (torchrefl/synthetic/scan.py) and the rig
(torchrefl/rig/folder.py, runner.py) write, and the range file's scale and offset. An unknown key
anywhere is a CaptureError naming the file and the dotted key, like the config's.
"""

from __future__ import annotations

import difflib
import json
import math
from pathlib import Path

from torchrefl.config import read_yaml_mapping
from torchrefl.errors import CaptureError

SCAN_YAML = "scan.yaml"
#: section -> its keys (None: a value, not a section)
SCHEMA = {
    "kind": None,
    "saturation_level": None,
    "lights": None,
    "grid": {"angle_step_deg", "height_step_mm", "angle0_deg", "height0_mm", "rows", "columns"},
    "camera": {"distance_mm", "height_mm"},
    "light": {"intensity", "kappa"},
    "range": {"file", "scale_mm", "offset_mm"},
    "truth": {"file", "brdf"},
}
#: keys of one light: the synthetic scanner's (image, position_mm), a per-light intensity, the rig manifest's
LIGHT_KEYS = ("image", "position_mm", "intensity", "index", "requested_mm", "mpos", "grid", "time")


def _refuse_unknown(keys, valid, where: str, prefix: str = "") -> None:
    for key in keys:
        if key not in valid:
            near = difflib.get_close_matches(str(key), [str(v) for v in valid], n=1, cutoff=0.5)
            hint = f"; did you mean '{prefix}{near[0]}'?" if near else f"; valid keys here: {', '.join(sorted(valid))}"
            raise CaptureError(f"{where}: unknown key '{prefix}{key}'{hint}")


def _need(doc: dict, key: str, where: str, kind=dict):
    if key not in doc:
        raise CaptureError(f"{where}: missing key '{key}'")
    value = doc[key]
    if kind is not None and not isinstance(value, kind):
        raise CaptureError(f"{where}: key '{key}' must be a {kind.__name__}, got {type(value).__name__}")
    return value


def _number(doc: dict, key: str, where: str, positive: bool = False) -> float:
    value = _need(doc, key, where, kind=None)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CaptureError(f"{where}: key '{key}' must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise CaptureError(f"{where}: key '{key}' must be > 0, got {value!r}")
    return float(value)


def triple(value, key: str, where: str, positive: bool = False) -> list:
    ok = (
        isinstance(value, list)
        and len(value) == 3
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)
    )
    if not ok:
        raise CaptureError(f"{where}: key '{key}' must be a list of 3 finite numbers, got {value!r}")
    if positive and any(x <= 0 for x in value):
        raise CaptureError(
            f"{where}: key '{key}' must be 3 positive numbers (negative or zero light intensity?), got {value!r}"
        )
    return [float(x) for x in value]


def _check_sections(doc: dict, where: str) -> None:
    _refuse_unknown(doc, SCHEMA, where)
    for section, keys in SCHEMA.items():
        if keys is None or section not in doc:
            continue
        if not isinstance(doc[section], dict):
            raise CaptureError(f"{where}: key '{section}' must be a mapping, got {type(doc[section]).__name__}")
        _refuse_unknown(doc[section], keys, where, f"{section}.")
    if "saturation_level" in doc:
        level = _number(doc, "saturation_level", where)
        if not 0.0 < level <= 1.0:
            raise CaptureError(f"{where}: key 'saturation_level' = {level!r}, expected a value in (0, 1]")
    for key in ("file", "brdf"):
        if key in doc.get("truth", {}) and not isinstance(doc["truth"][key], str):
            raise CaptureError(f"{where}: key 'truth.{key}' must be a string, got {doc['truth'][key]!r}")


def _check_lights(lights: list, where: str) -> list:
    for i, entry in enumerate(lights):
        if not isinstance(entry, dict) or "image" not in entry or "position_mm" not in entry:
            raise CaptureError(f"{where}: lights[{i}] must have 'image' and 'position_mm' (got {entry!r})")
        _refuse_unknown(entry, LIGHT_KEYS, where, f"lights[{i}].")
        if not isinstance(entry["image"], str) or not entry["image"]:
            raise CaptureError(f"{where}: key 'lights[{i}].image' must be a file name, got {entry['image']!r}")
        entry["position_mm"] = triple(entry["position_mm"], f"lights[{i}].position_mm", where)
        if "intensity" in entry:
            entry["intensity"] = triple(entry["intensity"], f"lights[{i}].intensity", where, positive=True)
    return lights


def read_scan_yaml(folder) -> dict:
    """Parse and check scan.yaml; returns the document with 'lights' resolved to a list."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: capture folder not found")
    path = folder / SCAN_YAML
    where = str(path)
    doc = read_yaml_mapping(path, CaptureError, "file (a cylindrical_scan capture needs scan.yaml)")
    _check_sections(doc, where)
    kind = doc.get("kind", "cylindrical_scan")
    if kind != "cylindrical_scan":
        raise CaptureError(f"{where}: key 'kind' is '{kind}', expected 'cylindrical_scan'")
    grid = _need(doc, "grid", where)
    for key in ("angle_step_deg", "height_step_mm"):
        _number(grid, key, f"{where} [grid]", positive=True)
    for key in ("angle0_deg", "height0_mm"):
        _number(grid, key, f"{where} [grid]")
    cam = _need(doc, "camera", where)
    _number(cam, "distance_mm", f"{where} [camera]", positive=True)
    _number(cam, "height_mm", f"{where} [camera]")
    light = _need(doc, "light", where)
    light["intensity"] = triple(
        _need(light, "intensity", f"{where} [light]", kind=None), "light.intensity", where, positive=True
    )
    if "kappa" in light:
        light["kappa"] = triple(light["kappa"], "light.kappa", where, positive=True)
    lights = doc.get("lights", [])
    if isinstance(lights, str):
        manifest = folder / lights
        lights, where = read_manifest(manifest), str(manifest)
    if not isinstance(lights, list):
        raise CaptureError(f"{where}: key 'lights' must be a list or the name of a manifest file")
    doc["lights"] = _check_lights(lights, where)
    return doc


def read_manifest(path: Path) -> list:
    """The rig's manifest.jsonl as a list of light entries (image, position_mm, ...)."""
    if not path.is_file():
        raise CaptureError(f"{path}: manifest file not found")
    entries = []
    for k, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            entries.append(json.loads(line))
        except json.JSONDecodeError as exc:
            raise CaptureError(f"{path}: line {k} is not valid JSON ({exc.msg})") from None
    return entries
