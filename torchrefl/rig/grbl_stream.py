"""Streaming many G-code lines to Grbl with its character-counting protocol."""

from __future__ import annotations

from collections import deque

from torchrefl.errors import RigError

RX_BUFFER_SIZE = 128  # Grbl's serial receive buffer (a ring buffer: 127 bytes usable)


def stream_lines(client, lines, timeout_s: float | None = None, rx_size: int = RX_BUFFER_SIZE) -> int:
    """Send many lines with GRBL's character-counting protocol: keep the bytes of unanswered
    lines (each with its newline) within the receive buffer (rx_size - 1 usable bytes), popping
    one line per `ok`/`error`. On the first error no further line is sent; the replies to the
    lines already in the buffer are read, then GrblErrorReply names the line. Returns the count."""
    limit = client.reply_s if timeout_s is None else float(timeout_s)
    cap = rx_size - 1
    sent: deque = deque()
    used = 0
    failure = None

    def pop():
        nonlocal used, failure
        line, n = sent.popleft()
        reply = client.next_reply(client.deadline(limit), f"to {line!r}")
        while reply != "ok" and not reply.startswith("error:"):
            reply = client.next_reply(client.deadline(limit), f"to {line!r}")
        used -= n
        if reply.startswith("error:") and failure is None:
            failure = (line, reply)

    count = 0
    for k, raw in enumerate(lines):
        line = raw.strip()
        n = len(line) + 1
        if n > cap:
            raise RigError(
                f"{client.port}: line {k + 1} ({line[:40]!r}...) has {n} bytes, more than GRBL's "
                f"{cap}-byte receive buffer"
            )
        while sent and used + n > cap:
            pop()
        if failure is not None:
            break
        client.write_line(line)
        sent.append((line, n))
        used += n
        count += 1
    while sent:
        pop()
    if failure is not None:
        line, reply = failure
        raise client.error_reply(reply, line)
    return count
