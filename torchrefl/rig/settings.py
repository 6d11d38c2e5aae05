"""Rig settings: typed sections with defaults and docs, strict YAML loading (configs/rig.yaml),
dotted `key=value` overrides. Unknown keys and wrong types raise ConfigError naming the key."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from torchrefl.config_fields import opt
from torchrefl.config_loading import _apply, _nest, parse_override, read_yaml_mapping
from torchrefl.errors import ConfigError


def section(cls, doc: str, **values):
    return field(default_factory=lambda: cls(**values), metadata={"doc": doc})


@dataclass
class AxisSettings:
    """One gantry axis: the GRBL axis letter, where head-frame 0 lies in machine coordinates, the
    direction, and the travel allowed (soft limits, machine coordinates as in GRBL's MPos)."""

    axis: str = opt("X", "GRBL axis letter driving this direction", choices=("X", "Y", "Z", "A"))
    origin_mm: float = opt(-250.0, "machine coordinate (MPos) at head-frame 0 on this axis, mm")
    sign: float = opt(
        1.0, "+1 when the machine coordinate grows with the head-frame coordinate, -1 otherwise", choices=(1.0, -1.0)
    )
    min_mm: float = opt(-495.0, "lowest machine coordinate a move may target, mm (soft limit)")
    max_mm: float = opt(-5.0, "highest machine coordinate a move may target, mm (soft limit)")


@dataclass
class TurntableSettings(AxisSettings):
    """An optional rotary axis turning the object (GRBL treats it as linear: set its steps/mm to steps/degree)."""

    enabled: bool = opt(False, "true when a turntable axis is wired and may be moved")


@dataclass
class GridSettings:
    """The light grid in the head frame (same layout as selection.grid of the fitting config)."""

    columns: int = opt(10, "grid positions along the lateral axis")
    rows: int = opt(6, "grid positions along the vertical axis")
    spacing_mm: float = opt(50.0, "grid spacing, mm")
    center_lateral_mm: float = opt(0.0, "lateral head-frame coordinate of the grid centre, mm")
    center_vertical_mm: float = opt(0.0, "vertical head-frame coordinate of the grid centre, mm")


@dataclass
class LightSettings:
    """Which GRBL output switches the light relay."""

    output: str = opt(
        "coolant",
        "coolant: M8 on / M9 off (flood pin); mist: M7 / M9; spindle: M3 S<power> / M5",
        choices=("coolant", "mist", "spindle"),
    )
    spindle_power: float = opt(1000.0, "S word sent with M3 when output is spindle (PWM duty = S / $30)")
    settle_s: float = opt(0.2, "wait after switching the light on before triggering, s")
    intensity: list = opt(
        [60000.0, 60000.0, 60000.0],
        "RGB radiant intensity Y of the light, written to a mesh_views capture's lights.json (full range x mm^2)",
    )


@dataclass
class BoardSettings:
    """What the rig requires of the Grbl board's `$$` settings, checked on every connect (docs/rig.md)."""

    limit_switches: bool = opt(
        True,
        "true: the board must home ($22=1) with soft limits ($20=1) and a travel "
        "($130-$132) containing every axis's min_mm..max_mm; false: a machine "
        "without limit switches: those checks are skipped, with a warning each time",
    )


@dataclass
class TimeoutSettings:
    reply_s: float = opt(2.0, "longest wait for GRBL's reply to a command or a '?' query, s")
    banner_s: float = opt(2.5, "wait for the start-up banner after opening the port before sending Ctrl-X, s")
    home_s: float = opt(0.0, "longest homing cycle, s; 0 = computed from the board's $130-$132, $24, $25, $27")
    status_retries: int = opt(
        3,
        "times a '?' is sent again after a malformed or missing status report before "
        "the rig stops motion (feed hold) and gives up",
    )
    move_s: float = opt(120.0, "longest wait for Idle after a move, s")
    poll_s: float = opt(0.05, "pause between '?' status polls, s")
    reconnect_s: float = opt(
        0.0,
        "after the port vanishes mid-capture, keep trying to reopen it this long "
        "(then re-home and continue); 0 = stop with a RigError",
    )


@dataclass
class CameraSettings:
    command: str = opt(
        "",
        "external trigger command; {path} is replaced by the image file to write "
        "(e.g. a scanner's texture export); empty = no external camera",
    )
    timeout_s: float = opt(120.0, "longest time the camera command may run, s")
    encoding: str = opt(
        "linear",
        "mesh_views captures: the images' encoding written to images.json: linear (16-bit linear PNG) or srgb "
        "(8-bit sRGB)",
        choices=("linear", "srgb"),
    )


@dataclass
class RigSettings:
    """Everything the rig needs; configs/rig.yaml documents each key."""

    port: str = opt("/dev/ttyUSB0", "serial port: device path, pty, or any pyserial URL (loop://, rfc2217://...)")
    baudrate: int = opt(115200, "serial speed (GRBL 1.1: 115200)")
    feed_mm_min: float = opt(3000.0, "feed rate of the G1 moves between light positions, mm/min")
    radial_mm: float = opt(
        300.0,
        "radial distance of the light plane from the rotation axis, mm "
        "(fixed: the gantry moves laterally and vertically only)",
    )
    position_tolerance_mm: float = opt(0.05, "largest allowed distance between requested and reached position, mm")
    home_on_start: bool = opt(True, "run the homing cycle ($H) before a capture (needed after power-up)")
    rehome_on_reset: bool = opt(
        False, "when the controller resets mid-capture, home again and continue instead of stopping with a RigError"
    )
    lateral: AxisSettings = section(AxisSettings, "axis carrying the light laterally")
    vertical: AxisSettings = section(
        AxisSettings, "axis carrying the light vertically", axis="Y", origin_mm=-150.0, min_mm=-295.0, max_mm=-5.0
    )
    turntable: TurntableSettings = section(
        TurntableSettings,
        "optional turntable axis (units: degrees)",
        axis="Z",
        origin_mm=0.0,
        min_mm=-360.0,
        max_mm=360.0,
    )
    grid: GridSettings = section(GridSettings, "light grid")
    light: LightSettings = section(LightSettings, "light switch")
    board: BoardSettings = section(BoardSettings, "Grbl settings the rig requires")
    timeouts: TimeoutSettings = section(TimeoutSettings, "timeouts")
    camera: CameraSettings = section(CameraSettings, "camera trigger")


def _check(cfg: RigSettings, where: str) -> None:
    for name in ("lateral", "vertical", "turntable"):
        ax = getattr(cfg, name)
        if ax.min_mm >= ax.max_mm:
            raise ConfigError(f"{where}: {name}.min_mm ({ax.min_mm}) must be below {name}.max_mm ({ax.max_mm})")
    axes = [cfg.lateral.axis, cfg.vertical.axis] + ([cfg.turntable.axis] if cfg.turntable.enabled else [])
    if len(set(axes)) != len(axes):
        raise ConfigError(f"{where}: lateral, vertical and turntable must use different GRBL axes (got {axes})")
    for key in ("feed_mm_min", "radial_mm", "position_tolerance_mm"):
        if getattr(cfg, key) <= 0:
            raise ConfigError(f"{where}: key '{key}' must be positive, got {getattr(cfg, key)}")
    y = cfg.light.intensity
    if not (isinstance(y, list) and len(y) == 3 and all(isinstance(v, (int, float)) and v > 0 for v in y)):
        raise ConfigError(f"{where}: key 'light.intensity' is {y!r}, expected 3 numbers > 0 (RGB, full range x mm^2)")
    if cfg.grid.columns < 1 or cfg.grid.rows < 1 or cfg.grid.spacing_mm <= 0:
        raise ConfigError(f"{where}: grid.columns and grid.rows must be >= 1 and grid.spacing_mm > 0")
    for key in ("reply_s", "banner_s", "move_s", "poll_s"):
        if getattr(cfg.timeouts, key) <= 0:
            raise ConfigError(f"{where}: key 'timeouts.{key}' must be positive")
    if cfg.timeouts.home_s < 0 or cfg.timeouts.status_retries < 0:
        raise ConfigError(f"{where}: keys 'timeouts.home_s' and 'timeouts.status_retries' must be >= 0")
    homes = [
        k
        for k, on in (
            ("home_on_start", cfg.home_on_start),
            ("rehome_on_reset", cfg.rehome_on_reset),
            ("timeouts.reconnect_s", cfg.timeouts.reconnect_s > 0),
        )
        if on
    ]
    if not cfg.board.limit_switches and homes:
        raise ConfigError(
            f"{where}: board.limit_switches is false (no switches, so no homing) but {', '.join(homes)} "
            f"asks the rig to home: set home_on_start: false, rehome_on_reset: false, "
            f"timeouts.reconnect_s: 0"
        )


def load_rig_settings(path=None, overrides=(), data: dict | None = None) -> RigSettings:
    """RigSettings from a YAML file (or a dict), then `dotted.key=value` overrides, checked."""
    cfg = RigSettings()
    where = "rig settings"
    if path is not None:
        path = Path(path)
        where = str(path)
        _apply(cfg, read_yaml_mapping(path, ConfigError, "rig settings file"), "", where)
    if data is not None:
        _apply(cfg, data, "", where)
    for text in overrides:
        key, value = parse_override(text)
        _apply(cfg, _nest(key, value), "", f"override '{text}'")
    _check(cfg, where)
    return cfg
