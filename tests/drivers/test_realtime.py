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


PINNING = r"""
import json, os, threading
from pathlib import Path
from graytrack.drivers import realtime
from graytrack.drivers.clock import ScaledClock
from graytrack.drivers.sim.process import RigProcess
from graytrack.drivers.sim.scenarios import build_rig

def threads(pid="self"):
    found = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            found.add(tuple(sorted(os.sched_getaffinity(int(task.name)))))
        except ProcessLookupError:  # a thread that ended between the listing and the reading
            pass
    return sorted(found)

allowed = sorted(os.sched_getaffinity(0))
stop = threading.Event()
earlier = threading.Thread(target=stop.wait)  # a thread started before the pinning goes along too
earlier.start()
refused = realtime.pin_process([max(allowed) + 1000])
previous = realtime.pin_process(allowed[:1])
pinned, spare = threads(), sorted(realtime.spare_cores())
rig = RigProcess(build_rig("paper", seed=0), ScaledClock(5.0)).start()
try:
    child = threads(rig.pid)
finally:
    rig.stop()
realtime.restore_process(previous)
stop.set()
earlier.join()
print(json.dumps({"allowed": allowed, "refused": refused is None, "previous": sorted(previous), "pinned": pinned,
                  "spare": spare, "child": child, "restored": threads(),
                  "spare_after": sorted(realtime.spare_cores())}))
"""


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="pinning needs a second core to leave")
def test_the_daemon_pins_every_thread_and_the_virtual_rig_runs_on_the_cores_it_left() -> None:
    # in a process of its own: pinning the test runner's threads would slow every other test
    import json
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", PINNING], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    allowed = seen["allowed"]
    assert seen["refused"]  # a core this process may not use: nothing pinned, said in the log
    assert seen["previous"] == allowed
    assert seen["pinned"] == [allowed[:1]]  # every thread, the one started before included
    assert seen["spare"] == allowed[1:]
    assert seen["child"] == [allowed[1:]]  # the rig's process beside the daemon, every thread of it
    assert seen["restored"] == [allowed]
    assert seen["spare_after"] == []


def test_no_cores_asked_pins_nothing() -> None:
    before = os.sched_getaffinity(0)
    assert realtime.pin_process([]) is None
    assert os.sched_getaffinity(0) == before
    assert realtime.spare_cores() == set()
