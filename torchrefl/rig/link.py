"""Line-oriented serial I/O over pyserial: any URL `serial.serial_for_url` opens (a device path,
a pseudo-terminal, `loop://`), reads with deadlines, and a reopen after the port vanished."""

from __future__ import annotations

import time

import serial

from torchrefl.errors import RigError

try:  # POSIX: pyserial's flush (tcdrain) raises termios.error, not an OSError, when a USB port vanishes
    import termios

    PORT_ERRORS: tuple = (termios.error,)
except ImportError:  # pragma: no cover - Windows
    PORT_ERRORS = ()


class PortLost(RigError):
    """The serial port failed under us (unplugged, device gone); `SerialLink.reopen` may bring it back."""


class NoReply(RigError):
    """The device sent nothing within the allowed time."""


class SerialLink:
    """A serial port read line by line.

    url: device path, pty path or pyserial URL; baudrate: bits/s; poll_s: pyserial read timeout
    used for one read call (the deadlines of `readline` are built from it).
    Lines are returned as raw bytes without the trailing CR/LF; decoding is the caller's job.
    """

    def __init__(self, url: str, baudrate: int = 115200, poll_s: float = 0.02):
        self.url = str(url)
        self.baudrate = int(baudrate)
        self.poll_s = float(poll_s)
        self._port = None
        self._buf = bytearray()

    # ---------------------------------------------------------------- open / close

    def open(self) -> "SerialLink":
        try:
            self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.poll_s)
        except (serial.SerialException, OSError, ValueError, *PORT_ERRORS) as exc:
            self._port = None
            raise RigError(f"cannot open serial port {self.url} at {self.baudrate} baud: {exc}") from None
        self._buf.clear()
        return self

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def close(self) -> None:
        port, self._port = self._port, None
        self._buf.clear()
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError, *PORT_ERRORS):
                pass

    def reopen(self, within_s: float, interval_s: float = 0.05) -> None:
        """Close and open the same URL again, retrying until `within_s` seconds have passed
        (a USB adapter or a pty takes a moment to reappear). Raises PortLost naming the port."""
        self.close()
        deadline = time.monotonic() + max(float(within_s), 0.0)
        last = None
        while True:
            try:
                self.open()
                return
            except RigError as exc:
                last = exc
            if time.monotonic() >= deadline:
                raise PortLost(f"serial port {self.url} did not come back within {within_s:.1f} s ({last})")
            time.sleep(interval_s)

    def __enter__(self) -> "SerialLink":
        if not self.is_open:
            self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------- I/O

    def _need_port(self):
        if self._port is None:
            raise PortLost(f"serial port {self.url} is not open")
        return self._port

    def _lost(self, what: str, exc: Exception) -> PortLost:
        self.close()
        return PortLost(f"serial port {self.url} failed during {what}: {exc}")

    def write(self, data: bytes) -> None:
        port = self._need_port()
        try:
            port.write(bytes(data))
            port.flush()
        except (serial.SerialException, OSError, *PORT_ERRORS) as exc:
            raise self._lost(f"write of {bytes(data)[:40]!r}", exc) from None

    def _fill(self) -> bool:
        """Read what is waiting (at most one poll interval); True when bytes arrived."""
        port = self._need_port()
        try:
            n = port.in_waiting
            chunk = port.read(n if n > 0 else 1)
        except (serial.SerialException, OSError, TypeError, *PORT_ERRORS) as exc:
            raise self._lost("read", exc) from None
        if chunk:
            self._buf.extend(chunk)
            return True
        return False

    def read_available(self) -> None:
        """Move the bytes already waiting in the OS buffer into the line buffer (never blocks)."""
        port = self._need_port()
        try:
            n = port.in_waiting
            chunk = port.read(n) if n > 0 else b""
        except (serial.SerialException, OSError, TypeError, *PORT_ERRORS) as exc:
            raise self._lost("read", exc) from None
        self._buf.extend(chunk)

    def readline(self, timeout_s: float) -> bytes | None:
        """The next line (bytes, CR/LF stripped), or None when no complete line arrived within timeout_s."""
        deadline = time.monotonic() + float(timeout_s)
        while True:
            k = self._buf.find(b"\n")
            if k >= 0:
                line = bytes(self._buf[:k])
                del self._buf[: k + 1]
                return line.rstrip(b"\r").lstrip(b"\r")
            if time.monotonic() >= deadline:
                return None
            self._fill()

    def drain(self, quiet_s: float = 0.05, max_s: float = 1.0) -> list[bytes]:
        """Read and return every line until the port stays quiet for quiet_s (at most max_s)."""
        lines = []
        end = time.monotonic() + max_s
        while time.monotonic() < end:
            line = self.readline(quiet_s)
            if line is None:
                break
            lines.append(line)
        return lines
