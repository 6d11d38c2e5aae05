"""The process's memory: its peak resident size since a reset, the device's peak, and what the machine has free.

Linux keeps the peak resident set (VmHWM, what `resource.getrusage` reports as ru_maxrss) per process; writing 5 to
/proc/self/clear_refs resets it, so that a run reports its own peak even in a process that ran others before
(scripts, tests). Elsewhere the peak is ru_maxrss since the process started.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import resource
import sys
from pathlib import Path

import torch

_MB = 2.0**20


def reset_peak() -> bool:
    """Reset the peak resident size to the current one (Linux) and torch's CUDA peaks; returns whether the resident
    peak was reset."""
    if torch.cuda.is_available():
        torch.cuda.reset_peak_memory_stats()
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def _status_mb(key: str) -> float | None:
    """A size line of /proc/self/status (VmRSS, VmHWM) in MiB; None where there is none."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def peak_resident_mb() -> float:
    """The process's peak resident memory in MiB (since the last reset_peak on Linux, since the start elsewhere).

    On Linux the larger of VmHWM and VmRSS (the peak is never below what is resident now), not ru_maxrss: that one
    also holds the peak of the process that started this one (the kernel keeps it across exec), so a run started
    from a large process (a batch runner, a notebook) would report its parent's memory. Elsewhere ru_maxrss."""
    status = [v for v in (_status_mb("VmHWM"), _status_mb("VmRSS")) if v is not None]
    if status:
        return max(status)
    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kib / _MB if sys.platform == "darwin" else kib / 1024.0  # macOS reports bytes, Linux KiB


def resident_mb() -> float:
    """The process's resident memory now, in MiB (Linux; the peak elsewhere)."""
    now = _status_mb("VmRSS")
    return peak_resident_mb() if now is None else now


def release_free_memory() -> bool:
    """Hand the C heap's free pages back to the system (glibc's malloc_trim); returns whether it could.

    numpy's and torch's arrays under glibc's mmap threshold (up to 32 MiB once large arrays have been freed) come
    from the heap, and the photon level's many such temporaries leave it fragmented: on the fold about 1.5 GB of
    free heap stayed resident between refreshes. Called before the stages that peak, so the free pages do not add
    to their peak; no effect on any result."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):  # another C library (musl) or none found
        return False
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    trim(0)
    return True


def available_mb() -> float | None:
    """Memory the machine can give new allocations now (MemAvailable of /proc/meminfo), in MiB; None where unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def peak_device_mb(device: torch.device) -> float | None:
    """The peak memory torch allocated on a CUDA device since the last reset_peak (None off CUDA), in MiB."""
    if device.type != "cuda":
        return None
    return torch.cuda.max_memory_allocated(device) / _MB
