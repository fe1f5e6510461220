"""Fits on threads (`ctjax._threads`): results in the items' order, errors where they come."""

import threading
import time

import pytest

from ctjax import ParameterError
from ctjax._threads import MAX_WORKERS, checked_workers, default_workers, in_order


def test_results_come_in_the_items_order_whichever_finishes_first():
    def slow_first(k):
        time.sleep(0.05 * (3 - k))
        return k * k

    assert list(in_order(slow_first, range(4), workers=3)) == [0, 1, 4, 9]
    assert list(in_order(slow_first, range(4), workers=1)) == [0, 1, 4, 9]


def test_an_error_is_raised_where_its_item_comes():
    def fails_at_two(k):
        if k == 2:
            raise ValueError("item 2")
        return k

    done = in_order(fails_at_two, range(4), workers=2)
    assert next(done) == 0 and next(done) == 1
    with pytest.raises(ValueError, match="item 2"):
        next(done)


def test_workers_are_checked_and_default_to_the_cores():
    assert 1 <= default_workers() <= MAX_WORKERS and checked_workers(None) == default_workers()
    assert checked_workers(3) == 3
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ParameterError, match="workers must be a positive integer"):
            checked_workers(bad)


def test_a_started_call_runs_beside_the_caller_and_hands_back_its_result_or_error():
    from ctjax._threads import started

    gate = threading.Event()

    def waits_for_the_caller(k):
        assert gate.wait(5), "the caller was blocked: started() did not return at once"
        return k + 1

    future = started(waits_for_the_caller, 41)
    gate.set()  # reached only if started() returned before its function finished
    assert future.result(timeout=5) == 42

    def fails():
        raise ValueError("in the thread")

    with pytest.raises(ValueError, match="in the thread"):
        started(fails).result(timeout=5)
