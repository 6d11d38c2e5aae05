"""The one threaded map over work units (ray chunks, lights, photon and path chunks, form-factor units, image
files): Embree and most of numpy release the GIL, so threads share the work of one process."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence, TypeVar

_U = TypeVar("_U")
_R = TypeVar("_R")


def thread_map(fn: Callable[[_U], _R], units: Sequence[_U], threads: int) -> list[_R]:
    """[fn(u) for u in units]: on a pool of min(threads, len(units)) threads when both exceed 1 (Embree and most
    of numpy release the GIL), in order on the calling thread otherwise. Results come in the units' order, and
    an exception raised by fn propagates (the first unit's in order when several fail). The one threaded map of
    the package: rays chunks (RayTracer), lights, photon and path chunks, form-factor units, image files."""
    threads = max(1, int(threads))
    if threads == 1 or len(units) <= 1:
        return [fn(u) for u in units]
    with ThreadPoolExecutor(min(threads, len(units))) as pool:
        return list(pool.map(fn, units))
