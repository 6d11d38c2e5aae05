"""The Grbl board's `$$` settings checked against the rig config before anything moves.

Checked on every connect (probe, home, move, capture, and after a reconnect or a reboot):
- `$13` report inches must be 0: the rig reads MPos in mm; in inches every position is 25.4x off;
- `$22` homing must be 1: the rig homes to establish machine coordinates (and Grbl needs it for `$20`);
- `$20` soft limits must be 1: Grbl's own refusal (ALARM:2) of a target outside the travel, a second
  line of defence behind the config's min_mm/max_mm (Grbl clears `$20` whenever `$22` is set to 0);
- `$130-$132` max travel with `$23` homing direction and `$27` pull-off must contain every configured
  axis's [min_mm, max_mm]: config limits wider than the machine would drive it into its end stops;
- `$32` laser mode must be 0 when the light is on the spindle output (laser mode switches the
  spindle only while moving).
`board.limit_switches: false` (a machine without switches) skips the `$20`, `$22` and travel checks
and warns on every connect.
"""

from __future__ import annotations

from dataclasses import dataclass

from torchrefl.errors import RigError
from torchrefl.rig.settings import RigSettings

OVERRIDE = "board.limit_switches: false"


@dataclass(frozen=True)
class BoardCheck:
    """One checked setting: its name, the value found, the value expected, ok (None: skipped) and the fix."""

    setting: str
    meaning: str
    found: str
    expected: str
    ok: bool | None
    fix: str = ""

    def line(self) -> str:
        verdict = {True: "ok", False: "WRONG", None: "not checked"}[self.ok]
        text = f"{self.setting}={self.found} ({self.meaning}): {verdict}, expected {self.expected}"
        return text + (f"; {self.fix}" if self.ok is False else "")


def machine_travel(board: dict, k: int) -> tuple[float, float]:
    """MPos range axis k can reach after homing: [-$13k, -$27] when it homes towards + (its `$23`
    bit clear, the switch at 0), [-$13k + $27, 0] when it homes towards - (the switch at -$13k)."""
    travel, pull = float(board[130 + k]), float(board[27])
    if int(board[23]) >> k & 1:
        return -travel + pull, 0.0
    return -travel, -pull


def _flag(board: dict, key: int, meaning: str, want: int, why: str, ok=None) -> BoardCheck:
    found = int(board.get(key, -1))
    ok = (found == want) if ok is None else ok
    return BoardCheck(
        f"${key}", meaning, str(found) if key in board else "missing", str(want), ok, f"send `${key}={want}` ({why})"
    )


def _axis(board: dict, name: str, ax, skipped: bool) -> BoardCheck:
    k = "XYZA".index(ax.axis)
    setting = f"${130 + k}"
    meaning = f"{ax.axis} max travel, holding {name}.min_mm..max_mm = [{ax.min_mm:g}, {ax.max_mm:g}]"
    if 130 + k not in board:
        return BoardCheck(
            setting,
            meaning,
            "missing",
            "a setting",
            False if not skipped else None,
            f"the board has no {ax.axis} axis: set {name}.axis to X, Y or Z in the rig config",
        )
    lo, hi = machine_travel(board, k)
    pull, inverted = float(board[27]), int(board[23]) >> k & 1
    expected = f"[{lo:g}, {hi:g}] (from ${130 + k}, $23, $27) to contain [{ax.min_mm:g}, {ax.max_mm:g}]"
    need = (pull - ax.min_mm) if inverted else -ax.min_mm
    fixes = []
    if ax.min_mm < lo - 1e-9:
        fixes.append(
            f"set {name}.min_mm >= {lo:g} in the rig config, or send `{setting}={need:g}` if the axis "
            f"really travels that far"
        )
    if ax.max_mm > hi + 1e-9:
        fixes.append(
            f"set {name}.max_mm <= {hi:g} in the rig config (the home switch and its ${27}={pull:g} mm "
            f"pull-off lie beyond)"
        )
    ok = None if skipped else not fixes
    return BoardCheck(setting, meaning, f"{float(board[130 + k]):g}", expected, ok, " and ".join(fixes))


def check_board(board: dict, rig: RigSettings) -> list[BoardCheck]:
    """Every check of this module's docstring, in order; skipped ones have ok None."""
    skip = not rig.board.limit_switches
    checks = [_flag(board, 13, "report inches", 0, "the rig reads positions in mm")]
    homing = _flag(board, 22, "homing", 1, f"or, on a machine without limit switches, set {OVERRIDE}")
    soft = _flag(
        board,
        20,
        "soft limits",
        1,
        "after `$22=1`; Grbl refuses `$20=1` without homing"
        if board.get(22) == 0
        else "Grbl then refuses targets outside the travel with ALARM:2",
    )
    if skip:
        homing, soft = (
            BoardCheck(c.setting, c.meaning, c.found, f"{c.expected} unless {OVERRIDE}", None) for c in (homing, soft)
        )
    checks += [homing, soft]
    axes = [("lateral", rig.lateral), ("vertical", rig.vertical)]
    if rig.turntable.enabled:
        axes.append(("turntable", rig.turntable))
    checks += [_axis(board, name, ax, skip) for name, ax in axes]
    if rig.light.output == "spindle":
        checks.append(
            _flag(
                board,
                32,
                "laser mode",
                0,
                "the light is on the spindle output, which laser mode switches only during motion",
            )
        )
    return checks


def require_board(board: dict, rig: RigSettings, port: str) -> list[BoardCheck]:
    """check_board, raising a RigError that lists every failed check and its fix."""
    checks = check_board(board, rig)
    failed = [c for c in checks if c.ok is False]
    if failed:
        raise RigError(
            f"{port}: the board's settings do not fit the rig config, so the rig will not move it: "
            + "; ".join(f"{c.setting} ({c.meaning}) is {c.found}, expected {c.expected}: {c.fix}" for c in failed)
        )
    return checks


def check_connected_board(client, rig: RigSettings, note=print, board: dict | None = None) -> list[BoardCheck]:
    """Read `$$` from a connected GrblClient (unless board gives it) and require_board; with the
    limit-switch override, note a warning (every time)."""
    checks = require_board(client.read_settings() if board is None else board, rig, client.port)
    if not rig.board.limit_switches:
        note(
            f"WARNING: {OVERRIDE} in the rig config: homing ($22), soft limits ($20) and the machine travel "
            f"($130-$132) are NOT checked; machine coordinates start wherever the carriage stood at power-up and "
            f"only the config's min_mm/max_mm keep the gantry off its ends"
        )
    return checks
