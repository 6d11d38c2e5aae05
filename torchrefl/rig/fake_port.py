"""The device end of the simulated board's serial line: a pseudo-terminal whose slave is reached
through a stable symlink (like /dev/serial/by-id/... for a USB adapter). Closing it removes the
symlink (the port "vanishes"); opening it again makes a new pty behind the same path."""

from __future__ import annotations

import os
import select
import tty


class PtyPort:
    """The master side of a pty behind the symlink `path`. Writes never block: when the client
    does not read and the pty is full, bytes are lost, as on a UART."""

    def __init__(self, path: str):
        self.path = path
        self.master: int | None = None
        self._slave: int | None = None

    @property
    def is_open(self) -> bool:
        return self.master is not None

    def open(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self.master, self._slave = master, slave
        tmp = self.path + ".new"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.path)

    def close(self) -> None:
        if os.path.lexists(self.path):
            os.unlink(self.path)
        for fd in (self.master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.master = self._slave = None

    def write(self, data: bytes) -> None:
        if self.master is None:
            return
        try:
            os.write(self.master, data)
        except OSError:
            pass  # full (BlockingIOError) or gone: the bytes are lost

    def read(self, wait_s: float) -> bytes:
        """What the client sent, waiting at most wait_s for the first byte (b'' when nothing)."""
        fd = self.master
        if fd is None:
            return b""
        try:
            readable, _, _ = select.select([fd], [], [], wait_s)
            return os.read(fd, 4096) if readable else b""
        except (OSError, ValueError):
            return b""
