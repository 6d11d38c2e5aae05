"""The `$$` settings of the simulated Grbl 1.1h board (torchrefl.rig.fake_grbl): defaults, the
`$n=value` store with Grbl's couplings, and the `$$` listing."""

from __future__ import annotations

import re

DEFAULT_SETTINGS = {
    0: 10,
    1: 25,
    2: 0,
    3: 0,
    4: 0,
    5: 0,
    6: 0,
    10: 1,
    11: 0.010,
    12: 0.002,
    13: 0,
    20: 1,
    21: 0,
    22: 1,
    23: 0,
    24: 25.0,
    25: 500.0,
    26: 250,
    27: 1.0,
    30: 1000,
    31: 0,
    32: 0,
    100: 80.0,
    101: 80.0,
    102: 80.0,
    110: 6000.0,
    111: 6000.0,
    112: 6000.0,
    120: 200.0,
    121: 200.0,
    122: 200.0,
    130: 500.0,
    131: 300.0,
    132: 200.0,
}
VALUE_RE = re.compile(r"[-+]?\d*\.?\d+")


def initial_settings(overrides: dict | None) -> dict:
    """DEFAULT_SETTINGS with overrides, made consistent as Grbl's EEPROM is: no soft limits
    ($20) without homing ($22)."""
    settings = dict(DEFAULT_SETTINGS)
    settings.update(overrides or {})
    if not settings[22]:
        settings[20] = 0
    return settings


def store_setting(settings: dict, key: int, text: str) -> str:
    """`$key=text` as Grbl 1.1h stores it (settings.c): returns `ok` or `error:N`. `$20=1` without
    homing is error:10; `$22=0` also clears `$20` (soft limits need homing)."""
    if key not in settings:
        return "error:3"
    if not VALUE_RE.fullmatch(text):
        return "error:2"
    value = float(text) if "." in text else int(text)
    if key == 20 and value and not settings[22]:
        return "error:10"
    settings[key] = value
    if key == 22 and not value:
        settings[20] = 0
    return "ok"


def setting_lines(settings: dict) -> list[str]:
    """The `$$` listing: one `$n=value` line per setting, floats with three decimals."""
    return [f"${k}={v:.3f}" if isinstance(v, float) else f"${k}={v}" for k, v in sorted(settings.items())]
