"""Strict reading of a capture folder's JSON files: every error names the file and the key path.

Key paths are written as in the docs: `cameras["cam0"].R`, `images[3].light`. Numbers must be finite
(JSON's NaN / Infinity extensions are refused), booleans are not numbers, unknown keys are errors.
"""

from __future__ import annotations

import difflib
import json
import math
from pathlib import Path

import numpy as np

from torchrefl.errors import CaptureError


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not a finite number")


def read_json(path: Path, what: str):
    """The parsed document of `path`; CaptureError naming the file when it is missing, unreadable or not
    valid JSON (with the line and column of the fault). `what` says what the file is for."""
    path = Path(path)
    if not path.is_file():
        state = "is a folder" if path.is_dir() else "missing"
        raise CaptureError(f"{path}: file {state} (expected {what})")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CaptureError(f"{path}: cannot read ({exc}); expected {what} as UTF-8 JSON") from None
    try:
        return json.loads(text, parse_constant=_refuse_constant)
    except json.JSONDecodeError as exc:
        raise CaptureError(f"{path}: not valid JSON at line {exc.lineno}, column {exc.colno} ({exc.msg})") from None
    except ValueError as exc:
        raise CaptureError(f"{path}: {exc} (JSON numbers must be finite)") from None


def refuse_unknown(doc: dict, valid, where: str, key: str) -> None:
    """CaptureError naming the first key of `doc` not in `valid` (with the nearest valid key)."""
    for name in doc:
        if name not in valid:
            near = difflib.get_close_matches(str(name), list(valid), n=1, cutoff=0.5)
            hint = f"did you mean '{near[0]}'?" if near else f"valid keys: {', '.join(sorted(valid))}"
            raise CaptureError(f"{where}: unknown key {key}.{name}; {hint}")


def need(doc: dict, name: str, where: str, key: str):
    """doc[name]; CaptureError naming `key.name` when it is missing."""
    if name not in doc:
        raise CaptureError(f"{where}: missing key {key}.{name}")
    return doc[name]


def mapping(value, where: str, key: str) -> dict:
    if not isinstance(value, dict):
        raise CaptureError(f"{where}: {key} must be a JSON object, got {type(value).__name__}")
    return value


def text(value, where: str, key: str) -> str:
    if not isinstance(value, str) or not value:
        raise CaptureError(f"{where}: {key} must be a non-empty string, got {value!r}")
    return value


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def number(value, where: str, key: str, positive: bool = False) -> float:
    if not _is_number(value):
        raise CaptureError(f"{where}: {key} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise CaptureError(f"{where}: {key} must be > 0, got {value!r}")
    return float(value)


def integer(value, where: str, key: str) -> int:
    """A positive integer (a JSON number without a fractional part)."""
    if not _is_number(value) or value != int(value) or value < 1:
        raise CaptureError(f"{where}: {key} must be a positive integer, got {value!r}")
    return int(value)


def array(value, shape: tuple[int, ...], where: str, key: str) -> np.ndarray:
    """A nested list of finite numbers of the given shape, as float64."""
    try:
        out = np.array(value, dtype=object)
    except ValueError:
        out = None
    ok = out is not None and out.shape == shape and all(_is_number(x) for x in out.reshape(-1))
    if not ok:
        described = " x ".join(str(n) for n in shape)
        raise CaptureError(f"{where}: {key} must be {described} finite numbers (nested lists), got {value!r}")
    return out.astype(np.float64)


def rgb(value, where: str, key: str) -> np.ndarray:
    """3 numbers > 0, or one number > 0 used for all three channels: (3,) float64."""
    values = [value] * 3 if _is_number(value) else value
    ok = isinstance(values, list) and len(values) == 3 and all(_is_number(x) and x > 0 for x in values)
    if not ok:
        raise CaptureError(f"{where}: {key} must be a number > 0 or 3 numbers > 0 (RGB), got {value!r}")
    return np.array(values, dtype=np.float64)
