"""How the simulated Grbl 1.1h board answers a line from its receive buffer: `$` system commands
(with Grbl's state rules), `$J=` jogs and G-code. A mixin of torchrefl.rig.fake_grbl.FakeGrbl,
whose state (settings, planner, modal state, outputs) it reads and changes."""

from __future__ import annotations

import re

from torchrefl.rig.fake_gcode import AXES, parse_block
from torchrefl.rig.fake_motion import Move, block_limits
from torchrefl.rig.fake_settings import setting_lines, store_setting

LINE_MAX = 80  # Grbl's LINE_BUFFER_SIZE
SYNCED_RE = re.compile(r"M0*[3-9]|G0*4(?![0-9])")  # Grbl waits for the end of motion
MOTION_RE = re.compile(r"(^|[^0-9.])G0*[01](?![0-9.])")
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"


class LineCommands:
    """The line interpreter of FakeGrbl (see its docstring for the behaviour)."""

    def _waits(self, line: str) -> bool:
        """True when line must stay in the receive buffer for now: a motion line (or jog) while the
        planner is full, M3-M9 / G4 while the machine moves."""
        busy = self._move is not None or bool(self._planner)
        if line.startswith("$J="):
            return len(self._planner) >= self.planner_blocks
        if line.startswith("$"):
            return False
        if SYNCED_RE.search(line):
            return busy
        motion = bool(MOTION_RE.search(line)) or (any(a in line for a in AXES) and "G4" not in line)
        return motion and len(self._planner) >= self.planner_blocks

    def _process_lines(self) -> None:
        while self.port.is_open and not self._critical and self._homing_left is None:
            k = self._rx.find(b"\n")
            if k < 0:
                return
            text = bytes(self._rx[:k]).rstrip(b"\r").decode("ascii", "replace")
            line = re.sub(r"\([^)]*\)|;.*$", "", text).replace(" ", "").upper()
            if self._waits(line):
                return
            del self._rx[: k + 1]
            self.lines.append(text)
            for hook in list(self._line_hooks):
                if hook[0] in line:
                    self._line_hooks.remove(hook)
                    self.port.write(hook[1])
            if self._silence_on is not None and self._silence_on in line:
                self._silent = True
            if self._silent:
                continue
            reply = self._injected_error(line) or self._execute(line)
            if reply:
                self._send(reply)

    def _injected_error(self, line: str) -> str | None:
        for rule in self._error_on:
            if rule[0] in line:
                if rule[2] > 0:
                    rule[2] -= 1
                    return None
                self._error_on.remove(rule)
                return f"error:{rule[1]}"
        return None

    def _execute(self, line: str) -> str | None:
        if len(line) > LINE_MAX:
            return "error:11"
        if not line:
            return "ok"
        if line.startswith("$"):
            return self._system(line[1:])
        if self.machine_state() in ("Alarm", "Jog"):
            return "error:9"
        return self._gcode(line)

    def _system(self, cmd: str) -> str | None:
        """`$...` (system.c): `$`, `$G`, `$X` in any state; `$$` unless moving or holding; `$J=`
        in Idle or Jog; everything else (`$H`, `$I`, `$n=`) in Idle or Alarm only (error:8)."""
        state = self.machine_state()
        if cmd == "":
            self._send(HELP)
            return "ok"
        if cmd == "G":
            m = self._modal
            self._send(
                f"[GC:{m['motion']} G54 G17 {m['units']} {m['distance']} G94 M5 "
                f"{'M8' if self.coolant else 'M9'} T0 F{m['feed'] or 0} S0]"
            )
            return "ok"
        if cmd == "X":
            if self.state == "Alarm":
                self._send("[MSG:Caution: Unlocked]")
                self.state = "Idle"
            return "ok"
        if cmd == "$":
            if state == "Run" or state.startswith("Hold"):
                return "error:8"
            for text in setting_lines(self.settings):
                self._send(text)
            return "ok"
        if cmd.startswith("J"):
            if state not in ("Idle", "Jog"):
                return "error:8"
            return self._jog(cmd[2:]) if cmd.startswith("J=") else "error:3"
        if state not in ("Idle", "Alarm"):
            return "error:8"
        return self._idle_system(cmd)

    def _idle_system(self, cmd: str) -> str | None:
        if cmd == "H":
            return self._start_homing()
        if cmd == "I":
            self._send(f"[VER:{self.version}.20190830:]")
            self._send("[OPT:V,15,128]")
            return "ok"
        m = re.fullmatch(r"(\d+)=(.*)", cmd)
        if m:
            return store_setting(self.settings, int(m.group(1)), m.group(2))
        return "error:3"

    def _outside_travel(self, target) -> bool:
        return any(not (-float(self.settings[130 + i]) - 1e-9 <= target[i] <= 1e-9) for i in range(len(AXES)))

    def _plan_end(self) -> list[float]:
        """Where the machine will stand once the queued blocks are done (the next block's start)."""
        if self._planner:
            return self._planner[-1].target
        return self._move.target if self._move is not None else self.mpos

    def _plan(self, target, feed_mm_min: float | None, jog: bool = False) -> None:
        """Queue a straight block to target at feed_mm_min (None: the rapid rate)."""
        start = self._plan_end()
        _, rapid, accel = block_limits(start, target, self.settings)
        speed = rapid if feed_mm_min is None else min(feed_mm_min / 60.0, rapid)
        self._planner.append(Move(start, target, speed, accel, jog=jog))

    def _jog(self, text: str) -> str:
        start = self._plan_end()
        block = parse_block(text, self._modal, start, self.wco, jog=True)
        if isinstance(block, str):
            return block
        if block.target is not None:
            if self.settings[20] and self._outside_travel(block.target):
                return "error:15"  # the jog is ignored; no alarm
            self._plan(block.target, block.feed, jog=True)
        return "ok"

    def _gcode(self, line: str) -> str | None:
        start = self._plan_end()
        block = parse_block(line, self._modal, start, self.wco)
        if isinstance(block, str):
            return block
        self._modal = block.modal
        if block.target is not None:
            if self.settings[20] and self._outside_travel(block.target):
                self._alarm(2)
                self._ok_after_reset = True  # Grbl sends this line's 'ok' after the reset
                return None
            self._plan(block.target, block.feed)
        self._switch(block.outputs)
        return "ok"
