"""Loading machinery of the typed configuration (torchrefl.config holds the schema and the entry points):
type coercion, choice and range checks, strict application of YAML mappings and dotted overrides onto
the dataclasses, cross-field validation, and reading YAML files.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from pathlib import Path
from typing import Any, Union

import yaml

from torchrefl.errors import ConfigError


def _is_section(tp) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _field_types(cls) -> dict:
    hints = typing.get_type_hints(cls)
    return {f.name: (f, hints[f.name]) for f in dataclasses.fields(cls)}


def _type_name(tp) -> str:
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return " or ".join(_type_name(a) for a in args) + " or null"
    return getattr(tp, "__name__", str(tp))


def yaml_value(value: Any) -> str:
    """`value` as it is written in a YAML file or a dotted.key=value override: null, true, [5, 11], outputs/x."""
    text = yaml.safe_dump(value, default_flow_style=True, width=10**6)
    return text.removesuffix("\n...\n").strip()


#: how to write a value of each plain type, for wrong-type messages (`example` is a valid value, e.g. the default)
_HOW_TO_WRITE = {
    bool: lambda example: "true or false",
    int: lambda example: f"a whole number such as {yaml_value(example if isinstance(example, int) else 5)}",
    float: lambda example: f"a number such as {yaml_value(example if isinstance(example, float) else 0.5)}",
    str: lambda example: "text (in YAML, quote text that reads as a number, true/false or null: '2024')",
    list: lambda example: f"a list such as {yaml_value(example) if example else '[5, 11]'}",
}


def _how_to_write(tp, value: Any, example: Any, optional: bool) -> str:
    """What a value of type `tp` looks like, with a hint for the usual slips (None for null, 1e-4 read as text)."""
    plain = list if typing.get_origin(tp) is list else tp
    how = _HOW_TO_WRITE[plain](example) if plain in _HOW_TO_WRITE else _type_name(tp)
    if optional:
        how += ", or null for none"
    if isinstance(value, str) and value.strip().lower() == "none":
        how += " (write null, not None)" if optional else " (this key cannot be null)"
    elif isinstance(value, str) and plain is float and _reads_as_number(value):
        how += f" (YAML reads {value} as text: write {yaml_value(float(value))})"
    return how


def _reads_as_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def _coerce(value: Any, tp, key: str, where: str, meta: dict) -> Any:
    """Check `value` against type `tp` (and choices/range); return it converted. meta["example"], when given,
    is a valid value of the key (its current value) shown in wrong-type messages."""
    origin = typing.get_origin(tp)
    optional = False
    if origin in (Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        optional = type(None) in args
        tp = [a for a in args if a is not type(None)][0]
    value = _coerce_type(value, tp, key, where, meta.get("example"), optional)
    _check_choices_and_range(value, key, where, meta)
    return value


def _coerce_type(value: Any, tp, key: str, where: str, example: Any = None, optional: bool = False) -> Any:
    """`value` checked against the plain (non-Optional) type `tp`; floats converted to float and checked finite."""
    origin = typing.get_origin(tp)
    bad = lambda: ConfigError(
        f"{where}: key '{key}' = {value!r} has the wrong type, expected {_how_to_write(tp, value, example, optional)}"
    )
    if tp is bool:
        if not isinstance(value, bool):
            raise bad()
    elif tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad()
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad()
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{where}: key '{key}' = {value!r} must be a finite number")
    elif tp is str:
        if not isinstance(value, str):
            raise bad()
    elif tp is list or origin is list:
        if not isinstance(value, list):
            raise bad()
    return value


def _check_choices_and_range(value: Any, key: str, where: str, meta: dict) -> None:
    """ConfigError unless `value` is one of meta's choices (when given) and within its low/high bounds."""
    choices = meta.get("choices") or ()
    if choices and value not in choices:
        near = difflib.get_close_matches(str(value), [str(c) for c in choices], n=1)
        hint = f" (did you mean '{near[0]}'?)" if near else ""
        raise ConfigError(f"{where}: key '{key}' = {value!r} is not one of {list(choices)}{hint}")
    low, high = meta.get("low"), meta.get("high")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if low is not None and value < low:
            raise ConfigError(f"{where}: key '{key}' = {value!r} must be >= {low}")
        if high is not None and value > high:
            raise ConfigError(f"{where}: key '{key}' = {value!r} must be <= {high}")


def _apply(obj, data: dict, prefix: str, where: str, sources: dict | None = None) -> None:
    if not isinstance(data, dict):
        raise ConfigError(
            f"{where}: key '{prefix.rstrip('.') or '<top>'}' must be a mapping, got {type(data).__name__}"
        )
    fields = _field_types(type(obj))
    public = [n for n, (f, _) in fields.items() if not f.metadata.get("internal")]
    for key, value in data.items():
        dotted = prefix + str(key)
        if key not in public:
            near = difflib.get_close_matches(str(key), public, n=1, cutoff=0.5)
            hint = f"; did you mean '{prefix}{near[0]}'?" if near else f"; valid keys here: {', '.join(public)}"
            raise ConfigError(f"{where}: unknown key '{dotted}'{hint}")
        f, tp = fields[key]
        if _is_section(tp):
            _apply(getattr(obj, key), value if value is not None else {}, dotted + ".", where, sources)
        else:
            setattr(obj, key, _coerce(value, tp, dotted, where, dict(f.metadata, example=getattr(obj, key))))
            if sources is not None:
                sources[dotted] = where


def _validate(cfg, where_of) -> None:
    """Cross-field checks; where_of(key) names where the key's value came from (the file or an override)."""
    if cfg.reflectance.sigma_min >= cfg.reflectance.sigma_max:
        raise ConfigError(
            f"{where_of('reflectance.sigma_min')}: reflectance.sigma_min ({cfg.reflectance.sigma_min}) must be < "
            f"reflectance.sigma_max ({cfg.reflectance.sigma_max})"
        )
    rc = cfg.reflectance
    if rc.minnaert_k is not None and rc.diffuse != "minnaert":
        raise ConfigError(
            f"{where_of('reflectance.minnaert_k')}: key 'reflectance.minnaert_k' is set but reflectance.diffuse is "
            f"'{rc.diffuse}'; "
            "set reflectance.diffuse: minnaert or drop the key"
        )
    if rc.diffuse != "lambert" and cfg.fit.model in ("radiosity", "photon"):
        raise ConfigError(
            f"{where_of('reflectance.diffuse')}: reflectance.diffuse '{rc.diffuse}' is for local transport only; "
            "fit.model "
            f"'{cfg.fit.model}' carries Lambertian interreflection (use reflectance.diffuse: lambert)"
        )
    if cfg.synthetic.minnaert_k != 1.0 and cfg.synthetic.indirect_samples > 0:
        raise ConfigError(
            f"{where_of('synthetic.minnaert_k')}: key 'synthetic.minnaert_k' = {cfg.synthetic.minnaert_k} needs "
            "synthetic.indirect_samples: 0 "
            "(the interreflection renderer is Lambertian)"
        )
    if cfg.reflectance.theta_specular_deg >= cfg.reflectance.theta_diffuse_deg:
        raise ConfigError(
            f"{where_of('reflectance.theta_specular_deg')}: reflectance.theta_specular_deg must be < "
            "reflectance.theta_diffuse_deg"
        )
    if len(cfg.capture.kappa) != 3 or not all(isinstance(k, (int, float)) and k > 0 for k in cfg.capture.kappa):
        raise ConfigError(
            f"{where_of('capture.kappa')}: key 'capture.kappa' must be a list of 3 positive numbers, got "
            f"{cfg.capture.kappa!r}"
        )
    if len(cfg.synthetic.size_mm) != 3 or not all(isinstance(k, (int, float)) and k > 0 for k in cfg.synthetic.size_mm):
        raise ConfigError(
            f"{where_of('synthetic.size_mm')}: key 'synthetic.size_mm' must be a list of 3 positive numbers, got "
            f"{cfg.synthetic.size_mm!r}"
        )
    for key, lst in (("fit.holdout", cfg.fit.holdout), ("capture.light_subset", cfg.capture.light_subset or [])):
        if not all(isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in lst):
            raise ConfigError(f"{where_of(key)}: key '{key}' must be a list of non-negative light indices, got {lst!r}")
    if cfg.capture.light_subset == []:
        raise ConfigError(
            f"{where_of('capture.light_subset')}: key 'capture.light_subset' is an empty list: it selects "
            "no light; list light indices, or null for all lights"
        )
    if not cfg.capture.kind.startswith("synthetic_") and not cfg.capture.path:
        raise ConfigError(
            f"{where_of('capture.kind')}: key 'capture.path' is required for capture.kind '{cfg.capture.kind}'"
        )
    for key in ("geometry.median_size", "geometry.fit_window", "fit.interpolation_window"):
        section, name = key.split(".")
        value = getattr(getattr(cfg, section), name)
        if value is not None and value % 2 != 1:
            raise ConfigError(f"{where_of(key)}: key '{key}' must be an odd number")


#: keys holding paths: relative in a file = relative to the file; on the command line = to the current folder
PATH_KEYS = ("capture.path", "selection.world.file")


def override_where(text: str) -> str:
    """How errors name a value given on the command line: `fit.holdout=[-1] on the command line`."""
    return f"{text} on the command line"


def parse_override(text: str) -> tuple[str, Any]:
    """'a.b=value' -> ('a.b', yaml value)."""
    if "=" not in text:
        raise ConfigError(f"{text} on the command line: expected dotted.key=value")
    key, raw = text.split("=", 1)
    try:
        value = yaml.safe_load(raw) if raw != "" else ""
    except yaml.YAMLError as exc:
        raise ConfigError(f"{override_where(text)}: value is not valid YAML ({exc.problem})") from None
    return key.strip(), value


def _nest(key: str, value: Any) -> dict:
    out: dict = {}
    cur = out
    parts = key.split(".")
    for p in parts[:-1]:
        cur[p] = {}
        cur = cur[p]
    cur[parts[-1]] = value
    return out


def read_yaml_mapping(path: Path, error: type = ConfigError, what: str = "file") -> dict:
    """The mapping in a YAML file ({} when empty); `error` naming the file for a missing file,
    invalid YAML (with its line) or a top level that is not a mapping."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: {what} not found")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text file (byte {exc.start} is not UTF-8); expected a YAML {what}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        loc = f" at line {mark.line + 1}" if mark else ""
        raise error(f"{path}: not valid YAML{loc}: {getattr(exc, 'problem', exc)}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise error(f"{path}: expected a mapping of keys at the top level, got {type(data).__name__}")
    return data
