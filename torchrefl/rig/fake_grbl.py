"""A simulated Grbl 1.1h board behind a real pseudo-terminal, for tests and dry runs.

The device end is a pty served by a thread (fake_port); clients open `FakeGrbl.path`, a stable
symlink to the pty slave, through pyserial. When the port "vanishes" the pty is closed and the
symlink removed; when it "comes back" a new pty is made and the board powers up again (banner,
alarm lock, position lost), as an Arduino does when its USB link re-enumerates.

What it does as Grbl 1.1h does (Grbl's interface docs and source, checked against a real board):
- banner `Grbl 1.1h ['$' for help]` at power-up and after Ctrl-X; with homing on ($22=1) power-up
  locks into Alarm with `[MSG:'$H'|'$X' to unlock]`;
- each line answered `ok` or `error:N`; `$$`, `$X`, `$H`, `$G`, `$I`, `$`, `$n=value` (fake_settings:
  `$22=0` clears `$20`, `$20=1` without homing is error:10); `$` commands other than `$G`, `$X`,
  `$` are error:8 unless Idle or Alarm (`$$` also in Jog), answered at once, not after the motion;
- `$J=` jogs: state Jog, error:15 when soft limits are on and the target is outside the travel,
  error:8 unless Idle or Jog; a feed hold during a jog cancels it;
- real-time `?` (status report with `WCO:` and `Ov:`/`A:` fields now and then), `!` feed hold in two
  phases (`Hold:1` while braking, `Hold:0` once stopped; a `~` during `Hold:1` is ignored), `~`,
  0x18 soft reset (ALARM:3 when it interrupts motion, ALARM:6 during homing);
- a 128-byte receive buffer (127 usable; bytes arriving when it is full are lost) and a planner of
  `planner_blocks` blocks (lines wait in the receive buffer while it is full); M3-M9 and G4 wait for
  the end of motion, as Grbl synchronises them;
- motion with acceleration (fake_motion: `$110-$112` rates, `$120-$122` accelerations); homing takes
  the time its settings give from where the carriage stands (grbl_homing), and the carriage keeps its
  place across a reboot while MPos restarts at 0; after homing MPos is -$27 (or -$13x + $27 for an
  axis whose `$23` bit is set);
- soft limits ($20=1) on the machine space [-$13x, 0]: ALARM:2 + `[MSG:Reset to continue]`; the `ok`
  of the offending line arrives after Ctrl-X, before the banner; alarms switch spindle and coolant off.
Where it differs from the real board: every duration is multiplied by `time_scale` (0.01 = 100x
faster than real) or follows an injected clock; blocks start and end at rest (no junction speeds);
`?` during homing is dropped rather than answered after it; G2/G3 arcs and most of G-code are absent.
Fault injection: silence, raw bytes, `error:N` to a chosen line, garbled or missing status reports,
`ALARM:N` mid-move, a reboot mid-move, the port vanishing (and coming back after a delay).
"""

from __future__ import annotations

import tempfile
import threading
import time
from collections import deque
from pathlib import Path

from torchrefl.rig.fake_commands import LineCommands
from torchrefl.rig.fake_gcode import AXES, initial_modal
from torchrefl.rig.fake_motion import Move
from torchrefl.rig.fake_port import PtyPort
from torchrefl.rig.fake_settings import DEFAULT_SETTINGS, initial_settings
from torchrefl.rig.grbl_homing import homing_seconds

__all__ = ["DEFAULT_SETTINGS", "FakeGrbl"]

RX_CAPACITY = 127  # 128-byte ring buffer, one slot always free


class FakeGrbl(LineCommands):
    """A Grbl 1.1h board simulated in a thread behind a pty.

    settings: overrides of Grbl's `$n` values; time_scale: multiplies every duration; home_time_s:
    a fixed homing duration before scaling (None: from the settings and the carriage's distance to
    the switches); carriage_mm: where the carriage stands at first power-up in the homed frame
    (None: at the switches, after the pull-off); planner_blocks: motion blocks queued at most;
    version: banner version; workdir: where the symlink `ttyGRBL` lives (a temp directory by
    default); wco: work coordinate offset (G54) for WPos reports ($10=0); clock: the time source in
    seconds (time.monotonic; tests pass a manual clock to step the simulation).
    """

    def __init__(
        self,
        settings: dict | None = None,
        *,
        time_scale: float = 1.0,
        home_time_s: float | None = None,
        carriage_mm=None,
        planner_blocks: int = 16,
        version: str = "1.1h",
        workdir=None,
        wco=(0.0, 0.0, 0.0),
        clock=time.monotonic,
    ):
        self.settings = initial_settings(settings)
        self.time_scale = float(time_scale)
        self.home_time_s = None if home_time_s is None else float(home_time_s)
        self.planner_blocks = int(planner_blocks)
        self.version = version
        self.clock = clock
        self._tmp = None
        if workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="fakegrbl-")
            workdir = self._tmp.name
        self.path = str(Path(workdir) / "ttyGRBL")
        self.port = PtyPort(self.path)
        self.wco = [float(v) for v in wco]
        # observable state (read by tests; guarded by self.lock)
        self.lock = threading.RLock()
        self.received = bytearray()  # every byte that reached the device, real-time ones included
        self.lines: list[str] = []  # every line the device processed, in order
        self.overflow_bytes = 0  # bytes lost to a full receive buffer
        self.max_rx_used = 0
        self.outputs_log: list[tuple[str, bool]] = []  # (output, on) changes: 'coolant', 'mist', 'spindle'
        self.moves_started = 0
        self.power_ups = 0
        self.mpos = [0.0, 0.0, 0.0]
        self._offset = list(self._home_position()) if carriage_mm is None else [float(v) for v in carriage_mm]
        self.state = "Idle"  # Idle, Alarm or Home; Run/Jog/Hold come from the motion
        self.coolant = self.mist = self.spindle = False
        # internals
        self._rx = bytearray()
        self._planner: deque = deque()
        self._move: Move | None = None
        self._hold: int | None = None  # None, 1 (braking) or 0 (held)
        self._critical = False
        self._homing_left = None  # simulated seconds of homing left
        self._ok_after_reset = False  # a line's 'ok' that Grbl sends after Ctrl-X (soft-limit alarm)
        self._status_wanted = False
        self._reports = 0
        self._modal = initial_modal()
        self._silent = False
        self._silence_on = None
        self._error_on: list = []  # [match, code, remaining skips]
        self._move_faults: dict = {}  # move number (1-based) -> (kind, kwargs)
        self._line_hooks: list = []  # [match, bytes] written before the reply to that line
        self._garble_reports = 0  # status reports still to garble
        self._drop_reports = 0  # status queries still to leave unanswered
        self._back_at = None
        self._stop = threading.Event()
        self._thread = None
        self._last = self.clock()

    # ---------------------------------------------------------------- lifecycle

    def start(self) -> "FakeGrbl":
        self.port.open()
        self._power_up()
        self._thread = threading.Thread(target=self._loop, name="FakeGrbl", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.port.close()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> "FakeGrbl":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ---------------------------------------------------------------- fault injection (thread-safe)

    def inject(self, data: bytes) -> None:
        """Write raw bytes to the client now (garbage, a stray banner, ...)."""
        with self.lock:
            self.port.write(bytes(data))

    def silence(self, after_line: str | None = None) -> None:
        """Stop answering (lines and `?`): now, or from the first line containing after_line."""
        with self.lock:
            if after_line is None:
                self._silent = True
            else:
                self._silence_on = after_line.upper()

    def speak(self) -> None:
        with self.lock:
            self._silent, self._silence_on = False, None

    def error_on(self, match: str, code: int, skip: int = 0) -> None:
        """Answer `error:code` instead of executing the (skip+1)-th line containing match."""
        with self.lock:
            self._error_on.append([match.upper(), int(code), int(skip)])

    def garbage_before(self, match: str, data: bytes) -> None:
        """Write data (e.g. b'\\xff\\xfe\\x00junk\\r\\n') just before the reply to the next line containing match."""
        with self.lock:
            self._line_hooks.append([match.upper(), bytes(data)])

    def garble_reports(self, count: int = 1) -> None:
        """Line noise: the next count status reports arrive with a '.' turned into ':' (as seen on a
        real cable: `<Run|MPos:-321.100,-98:613,-1.000|FS:3000,0>`)."""
        with self.lock:
            self._garble_reports += int(count)

    def drop_reports(self, count: int = 1) -> None:
        """The next count `?` queries are lost on the line (no report comes back)."""
        with self.lock:
            self._drop_reports += int(count)

    def alarm_during_move(self, move: int, code: int = 1) -> None:
        """Half-way through motion block number `move` (1-based, counted from now on as well as
        before): stop, ALARM:code (hard limit by default) + [MSG:Reset to continue], critical lock."""
        with self.lock:
            self._move_faults[int(move)] = ("alarm", {"code": int(code)})

    def reboot_during_move(self, move: int) -> None:
        """Half-way through motion block number `move`: the board reboots (brown-out): position
        lost, outputs off, banner (and the alarm lock when homing is enabled)."""
        with self.lock:
            self._move_faults[int(move)] = ("reboot", {})

    def vanish_during_move(self, move: int, down_s: float | None = 0.3) -> None:
        """Half-way through motion block number `move` the port disappears; it comes back after
        down_s seconds (None: only when come_back() is called) as a freshly powered-up board."""
        with self.lock:
            self._move_faults[int(move)] = ("vanish", {"down_s": down_s})

    def vanish(self, down_s: float | None = None) -> None:
        with self.lock:
            self._vanish(down_s)

    def come_back(self) -> None:
        with self.lock:
            self._back_at = time.monotonic()

    @property
    def present(self) -> bool:
        return self.port.is_open

    def reboot(self) -> None:
        """Power-cycle the board now (a reset banner the client did not ask for)."""
        with self.lock:
            self._power_up()

    @property
    def carriage(self) -> list[float]:
        """Where the carriage really stands, in the frame homing establishes (MPos after homing)."""
        return [m + o for m, o in zip(self.mpos, self._offset)]

    # ---------------------------------------------------------------- output and state

    def _send(self, text: str) -> None:
        if not self._silent:
            self.port.write(text.encode("ascii") + b"\r\n")

    def _banner(self) -> None:
        self._send("")
        self._send(f"Grbl {self.version} ['$' for help]")
        if self.state == "Alarm":
            self._send("[MSG:'$H'|'$X' to unlock]")

    def machine_state(self) -> str:
        """The state a status report shows: Alarm, Home, Hold:1, Hold:0, Jog, Run or Idle."""
        if self.state in ("Alarm", "Home"):
            return self.state
        if self._hold is not None:
            return f"Hold:{self._hold}"
        if self._move is not None or self._planner:
            return "Jog" if self._jogging() else "Run"
        return "Idle"

    def _jogging(self) -> bool:
        block = self._move if self._move is not None else (self._planner[0] if self._planner else None)
        return block is not None and block.jog

    def _home_position(self) -> list[float]:
        """MPos after homing: -$27, or -$13x + $27 on an axis homing towards negative ($23 bit set)."""
        pull, mask = float(self.settings[27]), int(self.settings[23])
        return [(-float(self.settings[130 + k]) + pull) if mask >> k & 1 else -pull for k in range(len(AXES))]

    def _outputs_off(self) -> None:
        for name in ("coolant", "mist", "spindle"):
            if getattr(self, name):
                setattr(self, name, False)
                self.outputs_log.append((name, False))

    def _switch(self, outputs) -> None:
        for name, on in outputs:
            if getattr(self, name) != on:
                setattr(self, name, on)
                self.outputs_log.append((name, on))

    def _power_up(self) -> None:
        self.power_ups += 1
        self._offset = self.carriage  # the carriage stays; Grbl's position restarts at 0
        self.mpos = [0.0, 0.0, 0.0]
        self._clear_motion()
        self._outputs_off()
        self._critical = self._ok_after_reset = False
        self._modal = initial_modal()
        self.state = "Alarm" if self.settings[22] else "Idle"
        self._reports = 0
        self._banner()

    def _clear_motion(self) -> None:
        self._rx.clear()
        self._planner.clear()
        self._move = None
        self._hold = None
        self._homing_left = None
        self._status_wanted = False

    def _vanish(self, down_s) -> None:
        self._clear_motion()
        self._outputs_off()
        self.port.close()
        self._back_at = None if down_s is None else time.monotonic() + float(down_s)

    def _soft_reset(self) -> None:
        alarm = None
        if self._homing_left is not None:
            alarm = 6
        elif (self._move is not None or self._planner) and self._hold != 0:
            alarm = 3  # reset while moving: position lost (a completed hold, Hold:0, is safe)
        self._clear_motion()
        self._outputs_off()
        self._critical = False
        self._modal.update({"motion": "G0", "distance": "G90"})
        if alarm is not None:
            self.state = "Alarm"
            self._send(f"ALARM:{alarm}")
        elif self.state != "Alarm":
            self.state = "Idle"
        if self._ok_after_reset:  # the line that raised a soft-limit alarm completes now
            self._ok_after_reset = False
            self._send("ok")
        self._reports = 0
        self._banner()

    def _alarm(self, code: int, critical: bool = True) -> None:
        self._planner.clear()
        self._move = None
        self._hold = None
        self._rx.clear()
        self._outputs_off()
        self.state = "Alarm"
        self._critical = critical
        self._send(f"ALARM:{code}")
        if critical:
            self._send("[MSG:Reset to continue]")

    # ---------------------------------------------------------------- the loop

    def _loop(self) -> None:
        while not self._stop.is_set():
            if not self.port.is_open:
                with self.lock:
                    if self._back_at is not None and time.monotonic() >= self._back_at:
                        self._back_at = None
                        self.port.open()
                        self._power_up()
                time.sleep(0.005)
                self._last = self.clock()
                continue
            master = self.port.master
            data = self.port.read(0.002)
            with self.lock:
                if self.port.master != master:
                    continue
                now = self.clock()
                for b in data:
                    self._byte(b)
                self._advance((now - self._last) / self.time_scale)
                self._last = now
                self._process_lines()
                if self._status_wanted and self.port.is_open:
                    self._status_wanted = False
                    self._report()

    def _byte(self, b: int) -> None:
        self.received.append(b)
        if b == 0x18:
            self._soft_reset()
        elif b == ord("?"):
            if self._homing_left is None and not self._critical:
                self._status_wanted = True
        elif b == ord("!"):
            self._feed_hold()
        elif b == ord("~"):
            if self._hold == 0:  # a `~` while still braking (Hold:1) is ignored
                self._hold = None
        elif b >= 0x80:
            pass  # override commands: accepted, ignored
        elif len(self._rx) >= RX_CAPACITY:
            self.overflow_bytes += 1  # lost, as on the real UART
        else:
            self._rx.append(b)
            self.max_rx_used = max(self.max_rx_used, len(self._rx))

    def _feed_hold(self) -> None:
        if self.state != "Idle" or self._hold is not None:
            return  # Alarm, homing, or already holding
        moving = self._move is not None and not self._move.stopped
        self._hold = 1 if moving else 0  # Idle too: Grbl enters Hold:0 at once

    def _report(self) -> None:
        if self._silent or self.state == "Home":
            return
        if self._drop_reports:
            self._drop_reports -= 1
            return
        parts = [self.machine_state(), self._position_field()]
        if int(self.settings[10]) & 2:
            parts.append(f"Bf:{self.planner_blocks - len(self._planner)},{RX_CAPACITY + 1 - len(self._rx)}")
        speed = self._move.speed_now * 60.0 if self._move is not None else 0.0
        parts.append(f"FS:{speed:.0f},{1000 if self.spindle else 0}")
        if self._reports % 10 == 0:
            parts.append("WCO:" + ",".join(f"{v:.3f}" for v in self.wco))
        elif self._reports % 10 == 1:
            parts.append("Ov:100,100,100")
            accessories = ("S" if self.spindle else "") + ("F" if self.coolant else "") + ("M" if self.mist else "")
            if accessories:
                parts.append("A:" + accessories)
        self._reports += 1
        text = "<" + "|".join(parts) + ">"
        if self._garble_reports:
            self._garble_reports -= 1
            k = text.rfind(".", 0, text.find("|", text.find("|") + 1))
            text = text[:k] + ":" + text[k + 1 :]
        self._send(text)

    def _position_field(self) -> str:
        if int(self.settings[10]) & 1:
            return "MPos:" + ",".join(f"{v:.3f}" for v in self.mpos)
        return "WPos:" + ",".join(f"{m - o:.3f}" for m, o in zip(self.mpos, self.wco))

    # ---------------------------------------------------------------- time

    def _advance(self, dt: float) -> None:
        """Let dt simulated seconds pass: homing, or the planner's blocks (braking when holding)."""
        if self._homing_left is not None:
            self._homing_left -= dt
            if self._homing_left <= 0:
                self._finish_homing()
            return
        if self.state == "Alarm" or self._hold == 0:
            return
        while dt > 0:
            if self._move is None:
                if self._hold == 1 or not self._planner:
                    if self._hold == 1:
                        self._hold_complete()
                    return
                self._start_next_move()
            m = self._move
            dt = m.advance(dt, holding=self._hold == 1)
            self.mpos = m.position()
            if m.fault is not None and m.progress >= 0.5 * m.length:
                self._fire(m)
                return
            if self._hold == 1 and m.stopped:
                self._hold_complete()
                return
            if m.done:
                self.mpos = list(m.target)
                self._move = None

    def _start_next_move(self) -> None:
        self._move = self._planner.popleft()
        self._move.restart_from(self.mpos)
        self.moves_started += 1
        self._move.fault = self._move_faults.pop(self.moves_started, None)

    def _hold_complete(self) -> None:
        if self._jogging():
            self._move = None  # a feed hold cancels a jog: the rest of it is dropped
            self._planner.clear()
            self._hold = None
        else:
            self._hold = 0

    def _fire(self, m: Move) -> None:
        kind, kw = m.fault
        m.fault = None
        if kind == "alarm":
            self._alarm(kw["code"])
        elif kind == "reboot":
            self._power_up()
        elif kind == "vanish":
            self._vanish(kw["down_s"])

    def _start_homing(self) -> str | None:
        if not self.settings[22]:
            return "error:5"
        self.state = "Home"
        if self.home_time_s is not None:
            self._homing_left = self.home_time_s
        else:
            mask = int(self.settings[23])  # the switch: at 0, or at -$13x when the axis homes negative
            switch = [-float(self.settings[130 + k]) if mask >> k & 1 else 0.0 for k in range(len(AXES))]
            self._homing_left = homing_seconds([c - s for c, s in zip(self.carriage, switch)], self.settings)
        return None  # 'ok' when the cycle ends

    def _finish_homing(self) -> None:
        self._homing_left = None
        self.mpos = self._home_position()
        self._offset = [0.0, 0.0, 0.0]
        self.state = "Idle"
        self._send("ok")
