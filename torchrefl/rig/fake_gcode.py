"""The G-code subset the simulated Grbl 1.1h board understands: G0/G1 (G53, G90/G91, G20/G21),
G4, M3-M5, M7-M9, F; and `$J=` jog lines (G20/G21, G90/G91, G53, axis words and F only).
`parse_block` turns one upper-case line without spaces into a Block, or an `error:N` reply."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

AXES = "XYZ"
WORD_RE = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
OUTPUT_WORDS = {
    3: [("spindle", True)],
    4: [("spindle", True)],
    5: [("spindle", False)],
    7: [("mist", True)],
    8: [("coolant", True)],
    9: [("coolant", False), ("mist", False)],
    2: [],
    30: [],
}
JOG_GS = (20, 21, 53, 90, 91)


def initial_modal() -> dict:
    """The G-code parser state at power-up and after a reset."""
    return {"distance": "G90", "units": "G21", "motion": "G0", "feed": None}


@dataclass
class Block:
    """One parsed line: the parser state after it, the outputs it switches, and its motion target
    (machine coordinates, None when it does not move); rapid for G0; feed in mm/min for G1/jog."""

    modal: dict
    outputs: list = field(default_factory=list)
    target: list | None = None
    rapid: bool = False
    feed: float | None = None
    dwell: bool = False


def _words(line: str):
    words = WORD_RE.findall(line)
    if "".join(a + b for a, b in words) != line:
        return "error:1" if not re.match(r"^[A-Z]", line) else "error:2"
    gs, ms, vals = [], [], {}
    for letter, num in words:
        if letter == "G":
            gs.append(float(num))
        elif letter == "M":
            ms.append(float(num))
        elif letter in vals:
            return "error:25"
        else:
            vals[letter] = float(num)
    return gs, ms, vals


def _apply_gs(gs, modal: dict, jog: bool):
    """Updates modal in place; returns (g53, dwell) or an error reply."""
    g53 = dwell = False
    for g in gs:
        if jog and g not in JOG_GS:
            return "error:16"
        if g in (0, 1):
            modal["motion"] = f"G{int(g)}"
        elif g == 4:
            dwell = True
        elif g in (90, 91, 20, 21):
            modal["distance" if g >= 90 else "units"] = f"G{int(g)}"
        elif g == 53:
            g53 = True
        elif g not in (17, 54, 94):
            return "error:20"
    return g53, dwell


def _target(axes: dict, modal: dict, g53: bool, start, wco) -> list[float]:
    target = list(start)
    for i, a in enumerate(AXES):
        if a in axes:
            if modal["distance"] == "G91" and not g53:
                target[i] = start[i] + axes[a]
            else:
                target[i] = axes[a] + (0.0 if g53 else wco[i])
    return target


def parse_block(line: str, modal: dict, start, wco, jog: bool = False) -> Block | str:
    """A Block for line (G-code, or the text after `$J=` when jog), starting from the parser state
    modal and the machine position start; or the `error:N` Grbl answers."""
    parsed = _words(line)
    if isinstance(parsed, str):
        return parsed
    gs, ms, vals = parsed
    if jog and (ms or set(vals) - set(AXES) - {"F"}):
        return "error:16"
    modal = dict(modal, motion="G1") if jog else dict(modal)
    flags = _apply_gs(gs, modal, jog)
    if isinstance(flags, str):
        return flags
    g53, dwell = flags
    if jog and "F" not in vals:
        return "error:22"
    if "F" in vals:
        if vals["F"] < 0:
            return "error:4"
        modal["feed"] = vals["F"]
    outputs = []
    for m in ms:
        if m not in OUTPUT_WORDS:
            return "error:20"
        outputs += OUTPUT_WORDS[m]
    scale = 25.4 if modal["units"] == "G20" else 1.0
    axes = {a: vals[a] * scale for a in AXES if a in vals}
    block = Block(modal=modal, outputs=outputs, dwell=dwell)
    if axes and not dwell:
        if modal["motion"] == "G1" and not modal["feed"]:
            return "error:22"
        block.target = _target(axes, modal, g53, start, wco)
        block.rapid = modal["motion"] == "G0"
        block.feed = None if block.rapid else modal["feed"] * scale
    return block
