"""SCHED_FIFO for the calling thread only; threads it starts are ordinary; a refusal is said once."""

from __future__ import annotations

import errno
import logging
import os
import threading

import pytest

from graytrack.drivers import realtime


def _in_thread(work):
    out = []
    thread = threading.Thread(target=lambda: out.append(work()))
    thread.start()
    thread.join()
    return out[0]


def _policy() -> tuple[int, int]:
    return os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK, os.sched_getparam(0).sched_priority


def test_the_raised_thread_runs_fifo_and_the_threads_it_starts_do_not() -> None:
    def raise_then_spawn():
        took = realtime.raise_thread_priority(4, "test thread")
        return took, _policy(), _in_thread(_policy)

    took, raised, child = _in_thread(raise_then_spawn)
    if not took:
        pytest.skip("this machine refuses SCHED_FIFO (no CAP_SYS_NICE or RLIMIT_RTPRIO)")
    assert raised == (os.SCHED_FIFO, 4)
    assert child == (os.SCHED_OTHER, 0)
    assert _policy() == (os.SCHED_OTHER, 0), "the caller's thread is left alone"


def test_another_thread_is_raised_by_its_kernel_id_and_the_caller_is_left_alone() -> None:
    """The virtual rig's process raises its controller's thread, which holds the lock its camera needs."""
    ready, done, seen = threading.Event(), threading.Event(), []

    def holder():
        ready.set()
        done.wait(5.0)
        seen.append(_policy())

    thread = threading.Thread(target=holder)
    thread.start()
    ready.wait(5.0)
    took = realtime.raise_thread_priority(3, "test holder", thread.native_id)
    done.set()
    thread.join()
    if not took:
        pytest.skip("this machine refuses SCHED_FIFO (no CAP_SYS_NICE or RLIMIT_RTPRIO)")
    assert seen == [(os.SCHED_FIFO, 3)]
    assert _policy() == (os.SCHED_OTHER, 0)


def test_level_zero_changes_nothing() -> None:
    assert _in_thread(lambda: (realtime.raise_thread_priority(0, "t"), _policy())) == (False, (os.SCHED_OTHER, 0))


def test_a_refusal_is_said_once_and_leaves_normal_scheduling(monkeypatch: pytest.MonkeyPatch,
                                                             caplog: pytest.LogCaptureFixture) -> None:
    # An unprivileged process cannot be made here (the suite may run as root): the refusal is the kernel's EPERM.
    def refuse(*args: object) -> None:
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(realtime, "_said", set())
    with caplog.at_level(logging.INFO, logger="graytrack.realtime"):
        assert not realtime.raise_thread_priority(7, "frame loop")
        assert not realtime.raise_thread_priority(7, "event loop")
    lines = [r for r in caplog.records if "refused" in r.getMessage()]
    assert len(lines) == 1 and lines[0].levelno == logging.WARNING
    assert "realtime_priority = 7 refused (Operation not permitted)" in lines[0].getMessage()
    assert "LimitRTPRIO" in lines[0].getMessage()
