"""A GRBL 1.1 client over a SerialLink: handshake, settings, unlock, homing, absolute moves in
machine coordinates, waiting for Idle by polling `?`, feed hold / resume / soft reset, and
character-counting streaming through the 128-byte receive buffer.

Every `error:N` and `ALARM:N` becomes a RigError with GRBL's readable text; a start-up banner that
arrives when no reset was asked for (the board rebooted: brown-out, USB re-enumeration) raises
ControllerReset, because the machine position is lost and the rig must be homed again.
"""

from __future__ import annotations

import re
import time
from collections import deque
from dataclasses import dataclass, field

from torchrefl.errors import RigError
from torchrefl.rig.grbl_codes import POSITION_LOST_ALARMS, alarm_message, error_message
from torchrefl.rig.link import NoReply, SerialLink

RX_BUFFER_SIZE = 128        # GRBL's serial receive buffer (a ring buffer: 127 bytes usable)
SOFT_RESET = b"\x18"
BANNER_RE = re.compile(r"^Grbl (\S+) \['\$' for help\]$")
SETTING_RE = re.compile(r"^\$(\d+)=([-+]?\d*\.?\d+)$")
STATES = ("Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep")


class GrblErrorReply(RigError):
    """GRBL answered `error:N` to a command."""

    def __init__(self, message: str, code: int, command: str):
        super().__init__(message)
        self.code, self.command = code, command


class GrblAlarm(RigError):
    """GRBL raised `ALARM:N` (or reports the Alarm state): motion is locked out."""

    def __init__(self, message: str, code: int | None):
        super().__init__(message)
        self.code = code

    @property
    def position_lost(self) -> bool:
        return self.code is None or self.code in POSITION_LOST_ALARMS


class ControllerReset(RigError):
    """An unrequested start-up banner: the controller rebooted, its position is lost (re-home)."""


@dataclass
class _Deadline:
    end: float      # time.monotonic() value
    span: float     # the allowed seconds, for messages


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
    st = Status(state=state, substate=int(sub) if sub.isdigit() else None, mpos=mpos, wpos=wpos,
                feed=feed, fields=fields, raw=raw)
    return st, wco


class GrblClient:
    """Talks GRBL 1.1 over an open SerialLink.

    reply_s: how long any command may take to answer (homing and motion have their own limits);
    poll_s: pause between `?` polls while waiting for Idle; banner_s: how long to wait for the
    start-up banner after opening before sending a soft reset; log: callable(str) for notes
    (garbage lines, [MSG:...] feedback).
    """

    def __init__(self, link: SerialLink, *, reply_s: float = 2.0, home_s: float = 60.0, move_s: float = 120.0,
                 poll_s: float = 0.05, banner_s: float = 2.5, log=None):
        self.link = link
        self.reply_s, self.home_s, self.move_s = float(reply_s), float(home_s), float(move_s)
        self.poll_s, self.banner_s = float(poll_s), float(banner_s)
        self.log = log or (lambda msg: None)
        self.banner: str | None = None
        self.version: str | None = None
        self.settings: dict[int, float] = {}
        self.messages: list[str] = []      # [MSG:...] and other feedback, in arrival order
        self.garbage: list[bytes] = []     # lines that were not ASCII or not GRBL grammar
        self.last_status: Status | None = None
        self.alarm: int | None = None      # last ALARM code seen and not yet cleared
        self._wco: tuple | None = None
        self._expect_banner = False

    @property
    def port(self) -> str:
        return self.link.url

    # ---------------------------------------------------------------- line reading

    def _classify(self, raw: bytes) -> str | None:
        """Decode one line; None for lines to skip (garbage, empty, feedback), else the text."""
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            self.garbage.append(raw)
            self.log(f"{self.port}: ignored a line that is not ASCII: {raw[:60]!r}")
            return None
        text = text.strip()
        if not text:
            return None
        if any(ord(c) < 32 or ord(c) == 127 for c in text):
            self.garbage.append(raw)
            self.log(f"{self.port}: ignored a line with control characters: {raw[:60]!r}")
            return None
        return text

    def _handle(self, raw: bytes, what: str, want_status: bool = False) -> str | None:
        """Process one received line. Returns the text when it is a reply for the caller (ok, error:N,
        $n=v, or a status report when want_status); records feedback and status reports; raises
        GrblAlarm on ALARM:N and ControllerReset on an unrequested banner."""
        text = self._classify(raw)
        if text is None:
            return None
        if text.startswith("<") and text.endswith(">"):
            try:
                st, self._wco = parse_status(text, self._wco)
            except RigError as exc:
                self.garbage.append(raw)
                self.log(f"{self.port}: ignored a malformed status report ({exc})")
                return None
            self.last_status = st
            return text if want_status else None
        m = BANNER_RE.match(text)
        if m:
            self.banner, self.version = text, m.group(1)
            self._wco = None
            if self._expect_banner:
                self._expect_banner = False
                return text
            raise ControllerReset(
                f"{self.port}: the controller reset unexpectedly ('{text}' arrived while waiting for a reply {what}): "
                f"machine position is lost, home the rig again ($H) before moving")
        if text.startswith("ALARM:"):
            code = text[6:]
            self.alarm = int(code) if code.isdigit() else None
            msg = alarm_message(self.alarm) if self.alarm is not None else text
            raise GrblAlarm(f"{self.port}: {msg} (while waiting for a reply {what})", self.alarm)
        if text.startswith("[") and text.endswith("]"):
            self.messages.append(text)
            self.log(f"{self.port}: {text}")
            return None
        if text.startswith(">") and (text.endswith(":ok") or ":error:" in text):
            self.messages.append(text)      # a start-up line ran (its ':ok' is not ours to count)
            return None
        if text == "ok" or text.startswith("error:") or SETTING_RE.match(text) or text.startswith("$N"):
            return text
        self.garbage.append(raw)
        self.log(f"{self.port}: ignored an unrecognised line: {text[:60]!r}")
        return None

    def _next(self, deadline: "_Deadline", what: str, *, want_status: bool = False) -> str:
        """The next reply line for the caller (see _handle); silence raises NoReply naming `what`."""
        while True:
            raw = self.link.readline(max(deadline.end - time.monotonic(), 0.0))
            if raw is None:
                raise NoReply(f"no reply from {self.port} within {deadline.span:.1f} s {what}")
            text = self._handle(raw, what, want_status)
            if text is not None:
                return text

    def pump(self, what: str = "to the next command") -> None:
        """Process what already arrived, without waiting: an alarm or a reset banner pushed since
        the last exchange raises here; a stray reply (a late ok) is logged and dropped."""
        self.link.read_available()
        while True:
            raw = self.link.readline(0.0)
            if raw is None:
                return
            text = self._handle(raw, what)
            if text is not None:
                self.log(f"{self.port}: dropped a reply nobody waited for: {text!r}")

    @staticmethod
    def _deadline(seconds: float) -> "_Deadline":
        return _Deadline(time.monotonic() + float(seconds), float(seconds))

    def _error(self, reply: str, command: str) -> GrblErrorReply:
        code = reply[6:]
        n = int(code) if code.isdigit() else -1
        return GrblErrorReply(f"{self.port}: GRBL refused {command!r}: {error_message(n)}", n, command)

    # ---------------------------------------------------------------- commands

    def write_line(self, line: str) -> None:
        data = line.strip()
        if "\n" in data or "\r" in data:
            raise RigError(f"{self.port}: command {line!r} spans several lines")
        try:
            payload = (data + "\n").encode("ascii")
        except UnicodeEncodeError:
            raise RigError(f"{self.port}: command {line!r} is not ASCII") from None
        self.link.write(payload)

    def command(self, line: str, timeout_s: float | None = None) -> list[str]:
        """Send one line, wait for `ok`; returns the lines that came before it ($n=v, $N...).
        Raises GrblErrorReply on `error:N`, NoReply naming the command on silence."""
        self.pump(f"before sending {line.strip()!r}")
        self.write_line(line)
        deadline = self._deadline(self.reply_s if timeout_s is None else timeout_s)
        out = []
        while True:
            reply = self._next(deadline, f"to {line.strip()!r}")
            if reply == "ok":
                return out
            if reply.startswith("error:"):
                raise self._error(reply, line.strip())
            out.append(reply)

    def realtime(self, char: bytes) -> None:
        """Send a real-time command (`?`, `!`, `~`, 0x18): one byte, never buffered, no `ok`."""
        self.link.write(char)

    # ---------------------------------------------------------------- session

    def connect(self) -> str:
        """Handshake: wait for the start-up banner (boards that reset on open print it), else send a
        soft reset (Ctrl-X) and wait for it; then read one status report. Returns the banner."""
        self.banner = None
        self._wco = None
        self._expect_banner = True
        deadline = self._deadline(self.banner_s)
        got = False
        while not got:
            try:
                got = BANNER_RE.match(self._next(deadline, "after opening the port (expected the start-up banner)")) is not None
            except GrblAlarm:
                continue    # ALARM:3 before the banner: the board was reset while moving
            except NoReply:
                break
        self._expect_banner = False
        if not got:
            self.soft_reset()
        self._settle()
        self.status()
        return self.banner

    def _settle(self, quiet_s: float = 0.05) -> None:
        """Read the feedback that follows a banner ([MSG:'$H'|'$X' to unlock], start-up lines)."""
        end = time.monotonic() + quiet_s
        while time.monotonic() < end:
            raw = self.link.readline(max(end - time.monotonic(), 0.0))
            if raw is None:
                return
            text = self._classify(raw)
            if text and text.startswith("["):
                self.messages.append(text)
                self.log(f"{self.port}: {text}")
            elif text and text.startswith("ALARM:"):
                self.alarm = int(text[6:]) if text[6:].isdigit() else None

    def soft_reset(self) -> str:
        """Ctrl-X: stops motion at once (GRBL raises ALARM:3 when it was moving, position lost),
        switches spindle and coolant off, clears buffers; returns the banner."""
        self._expect_banner = True
        self.realtime(SOFT_RESET)
        deadline = self._deadline(self.reply_s)
        try:
            while True:
                try:
                    line = self._next(deadline, "to the soft reset Ctrl-X (expected the start-up banner)")
                except GrblAlarm:
                    continue        # ALARM:3 precedes the banner when a reset stops motion
                if BANNER_RE.match(line):
                    break
        finally:
            self._expect_banner = False
        self._settle()
        return self.banner

    def status(self, timeout_s: float | None = None) -> Status:
        """Send `?` and return the next status report (no `ok` follows a report)."""
        self.realtime(b"?")
        deadline = self._deadline(self.reply_s if timeout_s is None else timeout_s)
        while True:
            self._next(deadline, "to the status query '?'", want_status=True)
            st = self.last_status
            if st.mpos is None:        # WPos without a known WCO yet: ask again
                time.sleep(self.poll_s)
                self.realtime(b"?")
                continue
            if st.state != "Alarm":
                self.alarm = None
            return st

    def read_settings(self) -> dict[int, float]:
        """`$$` -> {setting number: value}, also kept in self.settings."""
        lines = self.command("$$")
        out = {}
        for text in lines:
            m = SETTING_RE.match(text)
            if m:
                out[int(m.group(1))] = float(m.group(2))
        if not out:
            raise RigError(f"{self.port}: '$$' returned no settings (got {lines!r})")
        self.settings = out
        return out

    def unlock(self) -> None:
        """`$X`: clear the alarm lock without homing (position is NOT re-established)."""
        self.command("$X")
        self.alarm = None

    def home(self) -> Status:
        """`$H`: run the homing cycle (GRBL answers `ok` when it has finished); returns the status after."""
        self.command("$H", timeout_s=self.home_s)
        self.alarm = None
        return self.wait_idle()

    def move_to(self, axes: dict, feed_mm_min: float | None = None, rapid: bool = False) -> None:
        """Queue an absolute move in machine coordinates: `G21 G90 G53 G1 X.. Y.. F..` (or G0).
        axes: {'X': mm, 'Y': mm, ...}. Returns once GRBL accepted the block (use wait_idle)."""
        if not axes:
            raise RigError(f"{self.port}: move_to needs at least one axis")
        words = " ".join(f"{a.upper()}{float(v):.3f}" for a, v in axes.items())
        if rapid:
            line = f"G21 G90 G53 G0 {words}"
        else:
            if feed_mm_min is None or feed_mm_min <= 0:
                raise RigError(f"{self.port}: a G1 move needs a positive feed rate (got {feed_mm_min!r})")
            line = f"G21 G90 G53 G1 {words} F{float(feed_mm_min):.1f}"
        self.command(line)

    def wait_idle(self, timeout_s: float | None = None) -> Status:
        """Poll `?` until the state is Idle; returns that status. Raises GrblAlarm in the Alarm
        state, RigError when not Idle within timeout_s (default move_s)."""
        limit = self.move_s if timeout_s is None else float(timeout_s)
        end = time.monotonic() + limit
        while True:
            st = self.status()
            if st.state == "Idle":
                return st
            if st.state == "Alarm":
                raise GrblAlarm(f"{self.port}: the controller is in the Alarm state ({st.raw}); "
                                f"home ($H) or unlock ($X) it", self.alarm)
            if time.monotonic() >= end:
                raise RigError(f"{self.port}: not Idle within {limit:.1f} s (last status {st.raw})")
            time.sleep(self.poll_s)

    def feed_hold(self) -> None:
        """`!`: decelerate to a stop (state Hold:1 then Hold:0); resume with `~`."""
        self.realtime(b"!")

    def resume(self) -> None:
        """`~`: cycle start / resume after a feed hold."""
        self.realtime(b"~")

    # ---------------------------------------------------------------- streaming

    def stream(self, lines, timeout_s: float | None = None, rx_size: int = RX_BUFFER_SIZE) -> int:
        """Send many lines with GRBL's character-counting protocol: keep the bytes of unanswered
        lines (each with its newline) within the receive buffer (rx_size - 1 usable bytes), popping
        one line per `ok`/`error`. On the first error no further line is sent; the replies to the
        lines already in the buffer are read, then GrblErrorReply names the line. Returns the count."""
        limit = self.reply_s if timeout_s is None else float(timeout_s)
        cap = rx_size - 1
        sent: deque = deque()
        used = 0
        failure = None

        def pop():
            nonlocal used, failure
            line, n = sent.popleft()
            reply = self._next(self._deadline(limit), f"to {line!r}")
            while reply != "ok" and not reply.startswith("error:"):
                reply = self._next(self._deadline(limit), f"to {line!r}")
            used -= n
            if reply.startswith("error:") and failure is None:
                failure = (line, reply)

        count = 0
        for k, raw in enumerate(lines):
            line = raw.strip()
            n = len(line) + 1
            if n > cap:
                raise RigError(f"{self.port}: line {k + 1} ({line[:40]!r}...) has {n} bytes, more than GRBL's "
                               f"{cap}-byte receive buffer")
            while sent and used + n > cap:
                pop()
            if failure is not None:
                break
            self.write_line(line)
            sent.append((line, n))
            used += n
            count += 1
        while sent:
            pop()
        if failure is not None:
            line, reply = failure
            raise self._error(reply, line)
        return count
