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
from dataclasses import dataclass

from torchrefl.errors import RigError
from torchrefl.rig.grbl_codes import POSITION_LOST_ALARMS, alarm_message, error_message
from torchrefl.rig.grbl_homing import homing_timeout_s
from torchrefl.rig.grbl_status import Status, parse_status
from torchrefl.rig.grbl_stream import RX_BUFFER_SIZE, stream_lines
from torchrefl.rig.link import NoReply, SerialLink

__all__ = ["ControllerReset", "GrblAlarm", "GrblClient", "GrblErrorReply", "Status", "parse_status"]

SOFT_RESET = b"\x18"
BANNER_RE = re.compile(r"^Grbl (\S+) \['\$' for help\]$")
SETTING_RE = re.compile(r"^\$(\d+)=([-+]?\d*\.?\d+)$")


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


class _MalformedReport(RigError):
    """A status report arrived but could not be parsed (line noise); the query is worth repeating."""


@dataclass
class _Deadline:
    end: float  # time.monotonic() value
    span: float  # the allowed seconds, for messages


class GrblClient:
    """Talks GRBL 1.1 over an open SerialLink.

    reply_s: how long any command or status query may take to answer; home_s: the longest homing
    cycle (None: computed from the board's `$$`, see grbl_homing); move_s: the longest wait for Idle;
    poll_s: pause between `?` polls while waiting for Idle; banner_s: how long to wait for the
    start-up banner after opening before sending a soft reset; status_retries: how many times a `?`
    is sent again after a malformed or missing report; progress_s: seconds between progress notes
    while homing; log: callable(str) for notes (garbage lines, [MSG:...] feedback, retries).
    """

    def __init__(
        self,
        link: SerialLink,
        *,
        reply_s: float = 2.0,
        home_s: float | None = None,
        move_s: float = 120.0,
        poll_s: float = 0.05,
        banner_s: float = 2.5,
        status_retries: int = 3,
        progress_s: float = 10.0,
        log=None,
    ):
        self.link = link
        self.reply_s, self.move_s = float(reply_s), float(move_s)
        self.home_s = None if not home_s else float(home_s)
        self.poll_s, self.banner_s = float(poll_s), float(banner_s)
        self.status_retries, self.progress_s = int(status_retries), float(progress_s)
        self.status_retried = 0  # status queries sent again (malformed or missing report)
        self.rebooted = False  # an unrequested banner came: outputs off, locked until homed
        self.log = log or (lambda msg: None)
        self.banner: str | None = None
        self.version: str | None = None
        self.settings: dict[int, float] = {}
        self.messages: list[str] = []  # [MSG:...] and other feedback, in arrival order
        self.garbage: list[bytes] = []  # lines that were not ASCII or not GRBL grammar
        self.last_status: Status | None = None
        self.alarm: int | None = None  # last ALARM code seen and not yet cleared
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
                if want_status:
                    raise _MalformedReport(str(exc)) from None
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
            self.rebooted = True
            raise ControllerReset(
                f"{self.port}: the controller reset unexpectedly ('{text}' arrived while waiting for a reply {what}): "
                f"machine position is lost and Grbl switched its outputs (the light) off; it is locked until "
                f"homed, so home the rig again ($H) before moving"
            )
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
            self.messages.append(text)  # a start-up line ran (its ':ok' is not ours to count)
            return None
        if text == "ok" or text.startswith("error:") or SETTING_RE.match(text) or text.startswith("$N"):
            return text
        self.garbage.append(raw)
        self.log(f"{self.port}: ignored an unrecognised line: {text[:60]!r}")
        return None

    def next_reply(self, deadline: "_Deadline", what: str, *, want_status: bool = False) -> str:
        """The next reply line for the caller (see _handle); silence raises NoReply naming `what`."""
        while True:
            raw = self.link.readline(max(deadline.end - time.monotonic(), 0.0))
            if raw is None:
                raise NoReply(f"no reply from {self.port} within {deadline.span:.1f} s {what}")
            text = self._handle(raw, what, want_status)
            if text is not None:
                return text

    def _next_or_tick(self, deadline: "_Deadline", what: str, waiting=None) -> str:
        """next_reply, calling waiting(elapsed, limit) every progress_s seconds of silence."""
        if waiting is None:
            return self.next_reply(deadline, what)
        while True:
            tick = min(deadline.end, time.monotonic() + self.progress_s)
            try:
                return self.next_reply(_Deadline(tick, deadline.span), what)
            except NoReply:
                if time.monotonic() >= deadline.end:
                    raise
                waiting(deadline.span - (deadline.end - time.monotonic()), deadline.span)

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
    def deadline(seconds: float) -> "_Deadline":
        return _Deadline(time.monotonic() + float(seconds), float(seconds))

    def error_reply(self, reply: str, command: str) -> GrblErrorReply:
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

    def command(self, line: str, timeout_s: float | None = None, waiting=None) -> list[str]:
        """Send one line, wait for `ok`; returns the lines that came before it ($n=v, $N...).
        Raises GrblErrorReply on `error:N`, NoReply naming the command on silence. waiting:
        callable(elapsed s, limit s), called every progress_s seconds while no reply has come."""
        self.pump(f"before sending {line.strip()!r}")
        self.write_line(line)
        deadline = self.deadline(self.reply_s if timeout_s is None else timeout_s)
        out = []
        while True:
            reply = self._next_or_tick(deadline, f"to {line.strip()!r}", waiting)
            if reply == "ok":
                return out
            if reply.startswith("error:"):
                raise self.error_reply(reply, line.strip())
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
        deadline = self.deadline(self.banner_s)
        got = False
        while not got:
            try:
                got = (
                    BANNER_RE.match(self.next_reply(deadline, "after opening the port (expected the start-up banner)"))
                    is not None
                )
            except GrblAlarm:
                continue  # ALARM:3 before the banner: the board was reset while moving
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
        deadline = self.deadline(self.reply_s)
        try:
            while True:
                try:
                    line = self.next_reply(deadline, "to the soft reset Ctrl-X (expected the start-up banner)")
                except GrblAlarm:
                    continue  # ALARM:3 precedes the banner when a reset stops motion
                if BANNER_RE.match(line):
                    break
        finally:
            self._expect_banner = False
        self._settle()
        return self.banner

    def status(self, timeout_s: float | None = None) -> Status:
        """Send `?` and return the next status report (no `ok` follows a report). A malformed report
        (line noise) or none within timeout_s (default reply_s) is retried up to status_retries
        times, each retry counted in status_retried and logged. When the board still does not
        answer, a feed hold (`!`: the machine brakes to a stop and keeps its position) is sent and
        NoReply is raised."""
        wait = self.reply_s if timeout_s is None else float(timeout_s)
        for attempt in range(self.status_retries + 1):
            try:
                st = self._one_status(wait)
            except (_MalformedReport, NoReply) as exc:
                if attempt < self.status_retries:
                    self.status_retried += 1
                    self.log(
                        f"{self.port}: status query retried ({attempt + 1} of {self.status_retries}, "
                        f"{self.status_retried} in this session): {exc}"
                    )
                    continue
                self._stop_motion()
                raise NoReply(
                    f"no reply from {self.port} within {wait:.1f} s to the status query '?' "
                    f"({self.status_retries + 1} queries, the last: {exc}); sent a feed hold '!' to stop "
                    f"motion (the position is kept: check the machine, then `~` resumes or Ctrl-X resets)"
                ) from None
            if st.state != "Alarm":
                self.alarm = None
            return st

    def _one_status(self, wait_s: float) -> Status:
        self.realtime(b"?")
        deadline = self.deadline(wait_s)
        while True:
            self.next_reply(deadline, "to the status query '?'", want_status=True)
            st = self.last_status
            if st.mpos is not None:
                return st
            time.sleep(self.poll_s)  # WPos without a known WCO yet: ask again
            self.realtime(b"?")

    def _stop_motion(self) -> None:
        try:
            self.realtime(b"!")
        except RigError:
            pass  # the port is gone: nothing can be sent

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

    def homing_timeout(self) -> float:
        """home_s when given, else the bound grbl_homing computes from the board's `$$` (read now
        when not read yet)."""
        if self.home_s is not None:
            return self.home_s
        if not self.settings:
            self.read_settings()
        return homing_timeout_s(self.settings)

    def home(self, progress=None) -> Status:
        """`$H`: run the homing cycle (GRBL answers `ok` when it has finished, and no `?` meanwhile);
        progress (default: log) gets a note every progress_s seconds. Returns the status after."""
        limit = self.homing_timeout()
        note = progress or self.log
        source = "timeouts.home_s" if self.home_s is not None else "computed from $130-$132, $24, $25, $27"
        note(f"{self.port}: homing ($H), at most {limit:.0f} s ({source})")
        self.command(
            "$H",
            timeout_s=limit,
            waiting=lambda t, span: note(f"{self.port}: homing... {t:.0f} s of at most {span:.0f} s"),
        )
        self.alarm = None
        self.rebooted = False
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
                raise GrblAlarm(
                    f"{self.port}: the controller is in the Alarm state ({st.raw}); home ($H) or unlock ($X) it",
                    self.alarm,
                )
            if time.monotonic() >= end:
                raise RigError(f"{self.port}: not Idle within {limit:.1f} s (last status {st.raw})")
            time.sleep(self.poll_s)

    def hold_timeout(self) -> float:
        """The longest a feed hold may brake: the slowest axis from its top speed ($11x / $12x),
        doubled, plus reply_s; move_s when the settings were not read."""
        if not self.settings:
            return self.move_s
        brake = max(self.settings[110 + k] / 60.0 / self.settings[120 + k] for k in range(3))
        return 2.0 * brake + self.reply_s

    def _wait_held(self, limit: float, what: str) -> Status:
        """Poll `?` until the hold has completed (Hold:0) or the machine is not holding at all."""
        end = time.monotonic() + limit
        while True:
            st = self.status()
            if st.state == "Alarm":
                raise GrblAlarm(f"{self.port}: the controller is in the Alarm state ({st.raw}) {what}", self.alarm)
            if not (st.state == "Hold" and st.substate != 0):
                return st
            if time.monotonic() >= end:
                raise RigError(
                    f"{self.port}: the feed hold did not complete (Hold:0) within {limit:.1f} s {what} "
                    f"(last status {st.raw})"
                )
            time.sleep(self.poll_s)

    def feed_hold(self) -> Status:
        """`!`: brake to a stop; returns once the machine is held (Hold:0, within hold_timeout())."""
        self.realtime(b"!")
        return self._wait_held(self.hold_timeout(), "after the feed hold '!'")

    def resume(self) -> Status:
        """`~` after a feed hold: waits for the hold to complete first (Grbl ignores a `~` sent while
        still braking, Hold:1), then resumes; returns the first status that is no longer Hold."""
        st = self._wait_held(self.hold_timeout(), "before resuming")
        if st.state != "Hold":
            return st
        self.realtime(b"~")
        end = time.monotonic() + self.reply_s
        while st.state == "Hold":
            if time.monotonic() >= end:
                raise RigError(f"{self.port}: still {st.raw} {self.reply_s:.1f} s after the resume '~'")
            time.sleep(self.poll_s)
            st = self.status()
        return st

    # ---------------------------------------------------------------- streaming

    def stream(self, lines, timeout_s: float | None = None, rx_size: int = RX_BUFFER_SIZE) -> int:
        """Send many lines through the receive buffer (character counting, see grbl_stream)."""
        return stream_lines(self, lines, timeout_s, rx_size)
