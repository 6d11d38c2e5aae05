"""Grbl 1.1 real-time status reports: `<State[:n]|MPos:x,y,z|FS:f,s|WCO:...|Ov:...|A:...>`."""

from __future__ import annotations

from dataclasses import dataclass, field

from torchrefl.errors import RigError

STATES = ("Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep")


@dataclass
class Status:
    """One real-time status report. mpos: machine position (X, Y, Z[, A]) in mm (derived from
    WPos + WCO when the controller reports work positions)."""

    state: str
    substate: int | None
    mpos: tuple
    wpos: tuple | None = None
    feed: float | None = None
    fields: dict = field(default_factory=dict)
    raw: str = ""


def _floats(text: str, what: str, raw: str) -> tuple:
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise RigError(f"status report {raw!r}: field {what} is not a list of numbers") from None


def parse_status(raw: str, wco: tuple | None = None) -> tuple[Status, tuple | None]:
    """Parse `<State[:n]|MPos:x,y,z|...>`; returns (Status, the WCO in force after this report).

    WPos reports need a WCO (sent by GRBL in the first report after reset and every 10-30 reports);
    mpos is None when only WPos is known and no WCO has been seen yet.
    """
    if not (raw.startswith("<") and raw.endswith(">")):
        raise RigError(f"status report {raw!r}: expected '<State|MPos:...|...>'")
    parts = raw[1:-1].split("|")
    state, _, sub = parts[0].partition(":")
    if state not in STATES:
        raise RigError(f"status report {raw!r}: unknown machine state '{state}' (expected one of {', '.join(STATES)})")
    fields = {}
    for p in parts[1:]:
        key, sep, val = p.partition(":")
        if not sep:
            raise RigError(f"status report {raw!r}: field {p!r} has no ':'")
        fields[key] = val
    if "WCO" in fields:
        wco = _floats(fields["WCO"], "WCO", raw)
    mpos = wpos = None
    if "MPos" in fields:
        mpos = _floats(fields["MPos"], "MPos", raw)
        if wco is not None:
            wpos = tuple(m - o for m, o in zip(mpos, wco))
    elif "WPos" in fields:
        wpos = _floats(fields["WPos"], "WPos", raw)
        if wco is not None:
            mpos = tuple(w + o for w, o in zip(wpos, wco))
    else:
        raise RigError(f"status report {raw!r}: neither MPos nor WPos present")
    feed = None
    for key in ("FS", "F"):
        if key in fields:
            feed = _floats(fields[key], key, raw)[0]
    st = Status(
        state=state,
        substate=int(sub) if sub.isdigit() else None,
        mpos=mpos,
        wpos=wpos,
        feed=feed,
        fields=fields,
        raw=raw,
    )
    return st, wco
