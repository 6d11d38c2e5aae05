"""A simulated GRBL 1.1 controller behind a real pseudo-terminal, for tests and dry runs.

The device end is the pty master, served by a thread; clients open `FakeGrbl.path`, a stable
symlink to the pty slave (like /dev/serial/by-id/... for a USB adapter), through pyserial. When
the port "vanishes" the pty is closed and the symlink removed; when it "comes back" a new pty is
made, the symlink points at it, and the board powers up again (banner, alarm lock, position lost),
as an Arduino does when its USB link re-enumerates.

Protocol followed (GRBL 1.1 interface documentation):
- start-up banner `Grbl 1.1h ['$' for help]` at power-up and after Ctrl-X; with homing enabled
  ($22=1) power-up locks into Alarm with `[MSG:'$H'|'$X' to unlock]`;
- each line answered `ok` or `error:N`; `$$` settings, `$X` unlock, `$H` homing (takes time,
  `ok` when done, `?` ignored meanwhile), `$G`, `$I`, `$` help, `$n=value`;
- real-time `?` (status report, no `ok`), `!` feed hold, `~` resume, 0x18 soft reset (ALARM:3
  when it interrupts motion), never entering the receive buffer;
- a 128-byte ring receive buffer (127 usable): bytes arriving when it is full are lost;
- a planner of `planner_blocks` motion blocks: lines wait in the receive buffer while it is full;
  spindle/coolant/dwell/`$` commands wait until motion has finished (GRBL synchronises them);
- motion at the commanded feed (clamped to $110-$112), linear interpolation of MPos, status Run
  then Idle; `time_scale` multiplies every duration (0.01 = 100x faster than real);
- soft limits ($20=1) on GRBL's machine space [-$13x, 0]: ALARM:2 + `[MSG:Reset to continue]`;
  alarms switch spindle and coolant off; critical alarms ignore everything but Ctrl-X.
Fault injection: silence, raw bytes, `error:N` to a chosen line, `ALARM:N` mid-move, a reboot
(reset banner) mid-move, the port vanishing (and coming back after a delay).
"""

from __future__ import annotations

import os
import re
import select
import tempfile
import threading
import time
import tty
from collections import deque
from pathlib import Path

DEFAULT_SETTINGS = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
    20: 1, 21: 0, 22: 1, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0, 32: 0,
    100: 80.0, 101: 80.0, 102: 80.0, 110: 6000.0, 111: 6000.0, 112: 6000.0,
    120: 200.0, 121: 200.0, 122: 200.0, 130: 500.0, 131: 300.0, 132: 200.0,
}
AXES = "XYZ"
WORD_RE = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
RX_CAPACITY = 127          # 128-byte ring buffer, one slot always free
LINE_MAX = 80              # GRBL's LINE_BUFFER_SIZE


class _Move:
    def __init__(self, start, target, duration, feed):
        self.start, self.target, self.duration, self.feed = list(start), list(target), duration, feed
        self.elapsed = 0.0
        self.fault = None      # (kind, kwargs) injected to fire half-way


class FakeGrbl:
    """A GRBL 1.1 device simulated in a thread behind a pty.

    settings: overrides of GRBL's `$n` values; time_scale: multiplies motion and homing times;
    home_time_s: duration of a homing cycle before scaling; planner_blocks: motion blocks queued
    at most; version: banner version; workdir: where the stable symlink `ttyGRBL` lives (a temp
    directory by default); wco: work coordinate offset (G54), for WPos reports ($10=0).
    """

    def __init__(self, settings: dict | None = None, *, time_scale: float = 1.0, home_time_s: float = 1.0,
                 planner_blocks: int = 16, version: str = "1.1h", workdir=None, wco=(0.0, 0.0, 0.0)):
        self.settings = dict(DEFAULT_SETTINGS)
        self.settings.update(settings or {})
        self.time_scale = float(time_scale)
        self.home_time_s = float(home_time_s)
        self.planner_blocks = int(planner_blocks)
        self.version = version
        self._tmp = None
        if workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="fakegrbl-")
            workdir = self._tmp.name
        self.path = str(Path(workdir) / "ttyGRBL")
        self.wco = [float(v) for v in wco]
        # observable state (read by tests; guarded by self.lock)
        self.lock = threading.RLock()
        self.received = bytearray()        # every byte that reached the device, real-time ones included
        self.lines: list[str] = []         # every line the device processed, in order
        self.overflow_bytes = 0            # bytes lost to a full receive buffer
        self.max_rx_used = 0
        self.outputs_log: list[tuple[str, bool]] = []  # (output, on) changes: 'coolant', 'mist', 'spindle'
        self.moves_started = 0
        self.power_ups = 0
        self.mpos = [0.0, 0.0, 0.0]
        self.state = "Idle"
        self.coolant = self.mist = self.spindle = False
        # internals
        self._master = self._slave = None
        self._rx = bytearray()
        self._planner: deque = deque()
        self._move: _Move | None = None
        self._hold = False
        self._critical = False
        self._homing_left = None
        self._status_wanted = False
        self._reports = 0
        self._modal = {"distance": "G90", "units": "G21", "motion": "G0", "feed": None}
        self._silent = False
        self._silence_on = None
        self._error_on: list = []          # [match, code, remaining skips]
        self._move_faults: dict = {}       # move number (1-based) -> (kind, kwargs)
        self._line_hooks: list = []        # [match, bytes] written before the reply to that line
        self._back_at = None
        self._stop = threading.Event()
        self._thread = None
        self._last = time.monotonic()

    # ---------------------------------------------------------------- lifecycle

    def start(self) -> "FakeGrbl":
        self._open_pty()
        self._power_up()
        self._thread = threading.Thread(target=self._loop, name="FakeGrbl", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._close_pty()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> "FakeGrbl":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        target = os.ttyname(slave)
        tmp = self.path + ".new"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(target, tmp)
        os.replace(tmp, self.path)

    def _close_pty(self) -> None:
        if os.path.lexists(self.path):
            os.unlink(self.path)
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    # ---------------------------------------------------------------- fault injection (thread-safe)

    def inject(self, data: bytes) -> None:
        """Write raw bytes to the client now (garbage, a stray banner, ...)."""
        with self.lock:
            self._send_raw(bytes(data))

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
        return self._master is not None

    def reboot(self) -> None:
        """Power-cycle the board now (a reset banner the client did not ask for)."""
        with self.lock:
            self._reboot()

    # ---------------------------------------------------------------- output

    def _send_raw(self, data: bytes) -> None:
        if self._master is None:
            return
        try:
            os.write(self._master, data)
        except BlockingIOError:
            pass            # the client is not reading and the pty is full: bytes lost, as on a UART
        except OSError:
            pass

    def _send(self, text: str) -> None:
        if not self._silent:
            self._send_raw(text.encode("ascii") + b"\r\n")

    def _banner(self) -> None:
        self._send("")
        self._send(f"Grbl {self.version} ['$' for help]")
        if self.state == "Alarm":
            self._send("[MSG:'$H'|'$X' to unlock]")

    # ---------------------------------------------------------------- state changes

    def _outputs_off(self) -> None:
        for name in ("coolant", "mist", "spindle"):
            if getattr(self, name):
                setattr(self, name, False)
                self.outputs_log.append((name, False))

    def _power_up(self) -> None:
        self.power_ups += 1
        self.mpos = [0.0, 0.0, 0.0]
        self._clear_motion()
        self._outputs_off()
        self._critical = False
        self._modal = {"distance": "G90", "units": "G21", "motion": "G0", "feed": None}
        self.state = "Alarm" if self.settings[22] else "Idle"
        self._reports = 0
        self._banner()

    def _clear_motion(self) -> None:
        self._rx.clear()
        self._planner.clear()
        self._move = None
        self._hold = False
        self._homing_left = None
        self._status_wanted = False

    def _reboot(self) -> None:
        self._power_up()

    def _vanish(self, down_s) -> None:
        self._clear_motion()
        self._outputs_off()
        self._close_pty()
        self._back_at = None if down_s is None else time.monotonic() + float(down_s)

    def _soft_reset(self) -> None:
        alarm = None
        if self._homing_left is not None:
            alarm = 6
        elif (self._move is not None or self._planner) and not self._hold:
            alarm = 3             # reset while moving: position lost (a completed hold, Hold:0, is safe)
        self._clear_motion()
        self._outputs_off()
        self._critical = False
        self._modal.update({"motion": "G0", "distance": "G90"})
        if alarm is not None:
            self.state = "Alarm"
            self._send(f"ALARM:{alarm}")
        elif self.state not in ("Alarm",):
            self.state = "Idle"
        self._reports = 0
        self._banner()

    def _alarm(self, code: int, critical: bool = True) -> None:
        self._planner.clear()
        self._move = None
        self._hold = False
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
            fd = self._master
            if fd is None:
                with self.lock:
                    if self._back_at is not None and time.monotonic() >= self._back_at:
                        self._back_at = None
                        self._open_pty()
                        self._power_up()
                time.sleep(0.005)
                self._last = time.monotonic()
                continue
            try:
                readable, _, _ = select.select([fd], [], [], 0.002)
            except (OSError, ValueError):
                readable = []
            data = b""
            if readable:
                try:
                    data = os.read(fd, 4096)
                except (BlockingIOError, OSError):
                    data = b""
            with self.lock:
                if self._master != fd:
                    continue
                now = time.monotonic()
                for b in data:
                    self._byte(b)
                self._advance(now - self._last)
                self._last = now
                self._process_lines()
                if self._status_wanted and self._master is not None:
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
            if self._move is not None or self._planner:
                self._hold = True
        elif b == ord("~"):
            self._hold = False
        elif b >= 0x80:
            pass                      # override commands: accepted, ignored
        elif len(self._rx) >= RX_CAPACITY:
            self.overflow_bytes += 1  # lost, as on the real UART
        else:
            self._rx.append(b)
            self.max_rx_used = max(self.max_rx_used, len(self._rx))

    def _report(self) -> None:
        if self._silent:
            return
        if self.state == "Home" or self._homing_left is not None:
            return
        if self.state == "Alarm":
            state = "Alarm"
        elif self._hold and (self._move is not None or self._planner):
            state = "Hold:0"
        elif self._move is not None or self._planner:
            state = "Run"
        else:
            state = "Idle"
        mask = int(self.settings[10])
        if mask & 1:
            pos = "MPos:" + ",".join(f"{v:.3f}" for v in self.mpos)
        else:
            pos = "WPos:" + ",".join(f"{m - o:.3f}" for m, o in zip(self.mpos, self.wco))
        feed = self._move.feed if (self._move is not None and not self._hold) else 0
        parts = [state, pos]
        if mask & 2:
            parts.append(f"Bf:{self.planner_blocks - len(self._planner)},{RX_CAPACITY + 1 - len(self._rx)}")
        parts.append(f"FS:{feed:.0f},{1000 if self.spindle else 0}")
        if self._reports % 10 == 0:
            parts.append("WCO:" + ",".join(f"{v:.3f}" for v in self.wco))
        self._reports += 1
        self._send("<" + "|".join(parts) + ">")

    def _advance(self, dt: float) -> None:
        if self._homing_left is not None:
            self._homing_left -= dt
            if self._homing_left <= 0:
                self._homing_left = None
                pull = float(self.settings[27])
                self.mpos = [-pull, -pull, -pull]
                self.state = "Idle"
                self._send("ok")
            return
        if self.state == "Alarm" or self._hold:
            return
        while dt > 0:
            if self._move is None:
                if not self._planner:
                    return
                self._move = self._planner.popleft()
                self._move.start = list(self.mpos)
                self.moves_started += 1
                fault = self._move_faults.pop(self.moves_started, None)
                self._move.fault = fault
            m = self._move
            step = min(dt, m.duration - m.elapsed)
            m.elapsed += step
            dt -= step
            f = 1.0 if m.duration <= 0 else m.elapsed / m.duration
            if m.fault is not None and f >= 0.5:
                self.mpos = [a + 0.5 * (b - a) for a, b in zip(m.start, m.target)]
                kind, kw = m.fault
                m.fault = None
                if kind == "alarm":
                    self._alarm(kw["code"])
                elif kind == "reboot":
                    self._reboot()
                elif kind == "vanish":
                    self._vanish(kw["down_s"])
                return
            self.mpos = [a + f * (b - a) for a, b in zip(m.start, m.target)]
            if m.elapsed >= m.duration:
                self.mpos = list(m.target)
                self._move = None

    # ---------------------------------------------------------------- lines

    def _process_lines(self) -> None:
        while self._master is not None and not self._critical and self._homing_left is None:
            k = self._rx.find(b"\n")
            if k < 0:
                return
            raw = bytes(self._rx[:k]).rstrip(b"\r")
            text = raw.decode("ascii", "replace")
            line = re.sub(r"\([^)]*\)|;.*$", "", text).replace(" ", "").upper()
            busy = self._move is not None or bool(self._planner)
            motion = bool(re.search(r"(^|[^0-9.])G0*[01](?![0-9.])", line)) or (
                any(a in line for a in AXES) and not line.startswith("$") and "G4" not in line)
            if line.startswith("$") or re.search(r"M0*[3-9]|G0*4(?![0-9])", line):
                if busy:
                    return            # GRBL synchronises these with the end of motion
            elif motion and len(self._planner) >= self.planner_blocks:
                return                # planner full: the line stays in the receive buffer
            del self._rx[: k + 1]
            self.lines.append(text)
            for hook in list(self._line_hooks):
                if hook[0] in line:
                    self._line_hooks.remove(hook)
                    self._send_raw(hook[1])
            if self._silence_on is not None and self._silence_on in line:
                self._silent = True
            if self._silent:
                continue
            reply = None
            for rule in list(self._error_on):
                if rule[0] in line:
                    if rule[2] > 0:
                        rule[2] -= 1
                    else:
                        self._error_on.remove(rule)
                        reply = f"error:{rule[1]}"
                    break
            if reply is None:
                reply = self._execute(line)
            if reply:
                self._send(reply)

    def _execute(self, line: str) -> str | None:
        if len(line) > LINE_MAX:
            return "error:11"
        if not line:
            return "ok"
        if line.startswith("$"):
            return self._system(line)
        if self.state == "Alarm":
            return "error:9"
        return self._gcode(line)

    def _system(self, line: str) -> str | None:
        cmd = line[1:]
        if cmd == "":
            self._send("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]")
            return "ok"
        if cmd == "$":
            for k in sorted(self.settings):
                v = self.settings[k]
                self._send(f"${k}={v:.3f}" if isinstance(v, float) else f"${k}={v}")
            return "ok"
        if cmd == "X":
            if self.state == "Alarm":
                self._send("[MSG:Caution: Unlocked]")
                self.state = "Idle"
            return "ok"
        if cmd == "H":
            if not self.settings[22]:
                return "error:5"
            self.state = "Home"
            self._homing_left = self.home_time_s * self.time_scale
            return None                       # 'ok' when the cycle ends
        if cmd == "G":
            mods = f"{self._modal['motion']} G54 G17 {self._modal['units']} {self._modal['distance']} G94 M5 " \
                   f"{'M8' if self.coolant else 'M9'}"
            self._send(f"[GC:{mods} T0 F{self._modal['feed'] or 0} S0]")
            return "ok"
        if cmd == "I":
            self._send(f"[VER:{self.version}.20190825:]")
            self._send("[OPT:V,15,128]")
            return "ok"
        m = re.fullmatch(r"(\d+)=([-+]?\d*\.?\d+)", cmd)
        if m:
            key = int(m.group(1))
            if key not in self.settings:
                return "error:3"
            val = m.group(2)
            self.settings[key] = float(val) if "." in val else int(val)
            return "ok"
        return "error:3"

    def _gcode(self, line: str) -> str:
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
        modal = dict(self._modal)
        g53 = False
        dwell = False
        for g in gs:
            if g in (0, 1):
                modal["motion"] = f"G{int(g)}"
            elif g == 4:
                dwell = True
            elif g in (90, 91):
                modal["distance"] = f"G{int(g)}"
            elif g in (20, 21):
                modal["units"] = f"G{int(g)}"
            elif g == 53:
                g53 = True
            elif g in (17, 54, 94):
                pass
            else:
                return "error:20"
        if "F" in vals:
            if vals["F"] < 0:
                return "error:4"
            modal["feed"] = vals["F"]
        outputs = []
        for m in ms:
            if m in (3, 4):
                outputs.append(("spindle", True))
            elif m == 5:
                outputs.append(("spindle", False))
            elif m == 7:
                outputs.append(("mist", True))
            elif m == 8:
                outputs.append(("coolant", True))
            elif m == 9:
                outputs += [("coolant", False), ("mist", False)]
            elif m in (2, 30):
                pass
            else:
                return "error:20"
        scale = 25.4 if modal["units"] == "G20" else 1.0
        axes = {a: vals[a] * scale for a in AXES if a in vals}
        if axes and not dwell:
            if modal["motion"] == "G1" and not modal["feed"]:
                return "error:22"
            start = self._planner[-1].target if self._planner else (self._move.target if self._move else self.mpos)
            target = list(start)
            for i, a in enumerate(AXES):
                if a in axes:
                    if modal["distance"] == "G91" and not g53:
                        target[i] = start[i] + axes[a]
                    else:
                        target[i] = axes[a] + (0.0 if g53 else self.wco[i])
            if self.settings[20]:
                for i, a in enumerate(AXES):
                    if not (-float(self.settings[130 + i]) - 1e-9 <= target[i] <= 1e-9):
                        self._modal = modal
                        self._alarm(2)
                        return None
            dist = sum((b - a) ** 2 for a, b in zip(start, target)) ** 0.5
            vmax = min(float(self.settings[110 + i]) for i, a in enumerate(AXES) if abs(target[i] - start[i]) > 0) \
                if dist > 0 else 1.0
            feed = vmax if modal["motion"] == "G0" else min(modal["feed"] * scale, vmax)
            duration = dist / (feed / 60.0) * self.time_scale
            self._planner.append(_Move(start, target, duration, feed))
        elif dwell:
            pass
        self._modal = modal
        for name, on in outputs:
            if getattr(self, name) != on:
                setattr(self, name, on)
                self.outputs_log.append((name, on))
        return "ok"
