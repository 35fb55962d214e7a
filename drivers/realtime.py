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
from typing import Callable

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
