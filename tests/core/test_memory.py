"""torchrefl.core.memory: the peak resident size follows an allocation and its reset, the machine's free memory."""

import sys

import numpy as np
import pytest
from fresh_process import run_fresh

from torchrefl.core.memory import available_mb, peak_resident_mb, release_free_memory, reset_peak, resident_mb

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the peak is reset through /proc")


@linux
def test_the_peak_follows_an_allocation_and_its_reset():
    assert reset_peak()
    before = peak_resident_mb()
    assert abs(before - resident_mb()) < 20  # just reset: the peak is what is resident now
    resident_before = resident_mb()
    block = np.ones(200 * 2**20 // 8)  # 200 MiB, touched
    with_block = peak_resident_mb()
    rise = resident_mb() - resident_before
    del block
    release_free_memory()  # glibc can serve the block from its heap (seen after earlier tests), which free() keeps
    if rise < 180:  # the kernel kept the pages out of this process's resident set (swap, a tight cgroup)
        pytest.skip(f"a touched 200 MiB block raised the resident size by {rise:.0f} MiB only: no peak to follow")
    assert with_block - before > 180
    assert reset_peak()
    assert peak_resident_mb() < with_block - 150  # the block is gone and the reset forgot it


@linux
def test_the_machine_has_memory_available():
    free = available_mb()
    assert free is not None and 0 < free < 2**24  # some memory, and under 16 TiB


@linux
def test_the_free_heap_is_handed_back():
    """Blocks under glibc's mmap threshold come from the heap; freed between kept ones they stay resident until
    release_free_memory hands their pages back."""
    blocks = [np.ones(100 * 2**10 // 8) for _ in range(2000)]  # 2000 x 100 KiB, touched
    kept = blocks[::50]
    del blocks
    before = resident_mb()
    if not release_free_memory():
        pytest.skip("not glibc: no malloc_trim")
    freed = before - resident_mb()
    if freed < 1:
        pytest.skip("the C library handed the blocks back at once (no fragmented heap to trim)")
    assert freed > 100, freed
    assert len(kept) == 40


def own_peak_mb() -> float:
    """peak_resident_mb() of a process that has just started (imports only)."""
    return peak_resident_mb()


@linux
def test_a_process_started_from_a_large_one_reports_its_own_peak():
    """The kernel carries a process's peak across exec (ru_maxrss of the child starts at its parent's): a run
    started from a batch runner or a notebook holding gigabytes must not report them as its own."""
    block = np.ones(1024 * 2**20 // 8)  # 1 GiB, touched, held while the child starts
    if resident_mb() < 1000:
        pytest.skip("the touched block did not stay resident")
    child = run_fresh(__file__, "own_peak_mb")
    del block
    assert child < 800, child  # python, numpy and torch: about 250 MiB
