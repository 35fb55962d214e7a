"""Real-time scheduling for the threads a position stream waits on: the frame loop and the event loop,
and the grating poller, which holds the interpreter lock they need (a poller preempted while holding
it made the raised threads wait behind ordinary work: a priority inversion).

On a shared machine a thread that should run when a frame is ready can wait a millisecond or more
for a core (measured here: a plain process sleeping 1 ms wakes over 1 ms late about once a second
on an idle 2-core VM, several times a second under load), and every such wait is a late message
in the stream. ``SCHED_FIFO`` lets the frame loop and the event loop take a core as soon as they
are runnable. Only the calling thread is raised, with ``SCHED_RESET_ON_FORK`` so that threads it
creates (the calibration fit, the thread pool of blocking handlers) start as ordinary ones: a
fit must not starve the rest of the machine. The kernel's real-time throttling (95 % by default)
stays as the last guard. Needs an ``RLIMIT_RTPRIO`` of at least the level (deploy/graytrack.service
sets ``LimitRTPRIO``) or ``CAP_SYS_NICE``; without either the daemon logs a warning per thread and
runs them at normal priority.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Callable, Sequence

log = logging.getLogger("graytrack.realtime")
DEFAULT_LEVEL = 10  # the daemon's default: asked for everywhere, so a refusal of it is information, not a warning
_said: set[str] = set()


def raise_thread_priority(level: int, thread: str, native_id: int = 0) -> bool:
    """The calling thread (or the thread of ``native_id``: one that holds a lock the raised ones
    need) to ``SCHED_FIFO`` at ``level`` (1–99; 0 leaves it alone). True when it took effect."""
    if level <= 0:
        return False
    policy = getattr(os, "SCHED_FIFO", None)
    if policy is None or not hasattr(os, "sched_setscheduler"):
        _say_once(log.info, "realtime_priority: this platform has no SCHED_FIFO; the daemon runs at normal priority")
        return False
    try:
        os.sched_setscheduler(native_id, policy | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(level))
    except OSError as exc:
        say = log.info if level == DEFAULT_LEVEL else log.warning
        _say_once(say, f"realtime_priority = {level} refused ({exc.strerror or exc}): the {thread} and the others run "
                       "at normal priority; grant LimitRTPRIO or CAP_SYS_NICE (deploy/graytrack.service) or set 0")
        return False
    log.info("the %s runs SCHED_FIFO at priority %d", thread, level)
    return True


def _say_once(say: Callable[[str], None], message: str) -> None:
    """One line per kind of refusal, not one per thread."""
    kind = message.split("(")[0]
    if kind not in _said:
        _said.add(kind)
        say(message)


# -- cores ------------------------------------------------------------------------------------
# The daemon's threads share one interpreter lock, so they never run Python on two cores at once.
# Spread over the machine they hand the lock across cores (a wake-up on the other core each time)
# and other processes' threads preempt the one holding it; pinned to a core of their own they run
# in turn there and the rest of the machine (the virtual rig's process, clients) runs beside them.


def pin_process(cores: Sequence[int]) -> set[int] | None:
    """Every thread of this process onto ``cores`` (threads started later inherit it). Returns the
    cores it could run on before (to give back with :func:`restore_process`); None when nothing was
    pinned: no cores asked, a platform without affinity, or cores this process may not use (said in
    the log: the daemon runs unpinned rather than not at all)."""
    if not cores:
        return None
    if not hasattr(os, "sched_setaffinity"):
        _say_once(log.info, "cpu_cores: this platform cannot pin threads; the daemon runs on every core")
        return None
    allowed = os.sched_getaffinity(0)
    wanted = set(cores)
    if not wanted <= allowed:
        _say_once(log.warning, f"cpu_cores {sorted(wanted)} refused (this process may run on {sorted(allowed)} "
                               "only): the daemon runs on every core it may use")
        return None
    _set_every_thread(wanted)
    _spare.clear()
    _spare.update(allowed - wanted)
    log.info("the daemon's threads run on core(s) %s", sorted(wanted))
    return allowed


def restore_process(previous: set[int] | None) -> None:
    """Every thread back onto the cores :func:`pin_process` found (None: it pinned nothing)."""
    if previous is not None:
        _set_every_thread(previous)
        _spare.clear()


def spare_cores() -> set[int]:
    """The cores :func:`pin_process` took this process off (empty when it is not pinned): where a
    process standing in for separate hardware (the virtual rig's) belongs."""
    return set(_spare)


_spare: set[int] = set()


def _set_every_thread(cores: set[int]) -> None:
    tasks = Path("/proc/self/task")
    ids = [int(task.name) for task in tasks.iterdir()] if tasks.is_dir() else [0]
    for native_id in ids:
        try:
            os.sched_setaffinity(native_id, cores)
        except OSError:  # a thread that ended meanwhile
            pass
