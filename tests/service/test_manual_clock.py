"""The ManualClock: sleepers wake when time passes their deadline, and only then."""

from __future__ import annotations

import queue
import threading

import pytest

from graytrack.service.daemon.clock import HOST_CLOCK
from graytrack.service.daemon.manual_clock import ManualClock

pytestmark = pytest.mark.unit


def in_thread(call, *args):
    """Run ``call`` on a thread; ``result`` holds its return value or exception once it ends."""
    result: list[object] = []

    def run() -> None:
        try:
            result.append(call(*args))
        except Exception as exc:  # noqa: BLE001 - the test looks at it
            result.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread, result


def test_a_sleeper_wakes_once_time_passes_its_deadline_and_not_before() -> None:
    clock = ManualClock(start=50.0)
    thread, result = in_thread(clock.sleep, 2.0)
    clock.settle()
    clock.advance(1.5)
    clock.settle()
    assert thread.is_alive() and clock.blocked == 1, "1.5 s into a 2 s sleep"
    clock.advance(0.5)  # returns once the sleeper has left
    thread.join(5.0)
    assert not thread.is_alive() and result == [None] and clock.blocked == 0
    assert clock.now() == 52.0


def test_get_takes_an_item_put_before_the_deadline_and_times_out_after_it() -> None:
    clock = ManualClock()
    items: queue.Queue[str] = queue.Queue()
    thread, result = in_thread(clock.get, items, 0.25)
    clock.settle()
    clock.put(items, "frame")
    clock.advance(1.0)  # the item came first: it is taken, though the deadline has passed too
    thread.join(5.0)
    assert result == ["frame"]

    thread, result = in_thread(clock.get, items, 0.25)
    clock.settle()
    clock.advance(0.25)
    thread.join(5.0)
    assert len(result) == 1 and isinstance(result[0], queue.Empty)


def test_wait_returns_at_once_when_the_event_is_set_and_false_at_the_deadline() -> None:
    clock = ManualClock()
    stop = threading.Event()
    thread, result = in_thread(clock.wait, stop, 10.0)
    clock.settle()
    stop.set()
    thread.join(5.0)
    assert result == [True] and clock.now() == 1000.0, "an event needs no time to pass"
    thread, result = in_thread(clock.wait, threading.Event(), 10.0)
    clock.settle()
    clock.advance(10.0)
    thread.join(5.0)
    assert result == [False]


def test_settle_names_the_blocked_threads_when_none_blocks_again() -> None:
    clock = ManualClock()
    with pytest.raises(TimeoutError, match=r"manual clock at 1000 s: .* 0 blocked"):
        clock.settle(timeout_s=0.1)
    with pytest.raises(ValueError, match="time does not go back"):
        clock.advance(-1.0)


def test_the_host_clock_is_time_monotonic() -> None:
    import time

    before = time.monotonic()
    now = HOST_CLOCK.now()
    assert before <= now <= time.monotonic()
    items: queue.Queue[int] = queue.Queue()
    items.put(7)
    assert HOST_CLOCK.get(items, 0.0) == 7
    with pytest.raises(queue.Empty):
        HOST_CLOCK.get(items, 0.0)
    assert HOST_CLOCK.wait(threading.Event(), 0.0) is False
