"""thread_map against the plain loop [fn(u) for u in units]."""

import threading

import pytest

from torchrefl.core.threads import thread_map


@pytest.mark.parametrize("threads", [1, 2, 4])
@pytest.mark.parametrize("n", [0, 1, 2, 7])
def test_results_in_unit_order_like_the_loop(threads, n):
    units = [(i, 3 * i) for i in range(n)]
    assert thread_map(lambda u: u[0] + u[1], units, threads) == [i + 3 * i for i in range(n)]
    assert thread_map(lambda u: u * u, range(n), threads) == [u * u for u in range(n)]


def test_one_thread_or_one_unit_runs_on_the_calling_thread_and_more_use_a_pool():
    me = threading.get_ident()
    assert set(thread_map(lambda _: threading.get_ident(), range(5), 1)) == {me}
    assert thread_map(lambda _: threading.get_ident(), [0], 4) == [me]
    barrier = threading.Barrier(2, timeout=10)  # two units that must run at the same time
    assert thread_map(lambda u: barrier.wait() >= 0 and u, [1, 2], 2) == [1, 2]


def test_the_first_failing_unit_in_order_is_reported():
    def fn(u):
        if u in (3, 5):
            raise ValueError(f"unit {u}")
        return u

    for threads in (1, 2):
        with pytest.raises(ValueError, match="unit 3"):
            thread_map(fn, range(8), threads)
