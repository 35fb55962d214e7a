"""Operations of several requests (calibrate and follow, move and settle), written once for both clients.

A plan is a generator: it yields a :class:`~graytrack.client.routes.Call` to be sent (and is
resumed with its result) or a :class:`Pause`, and returns the operation's result. :func:`run`
drives it with blocking I/O and :func:`run_async` with asyncio; the decisions (when a job is
done, when the stage has settled, when to give up) live only here.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass
from typing import Any, Awaitable, Callable, Generator, TypeVar

from graytrack.client import routes
from graytrack.client.errors import CalibrationFailed, Conflict, GraytrackClientError, NotReady, WaitTimeout
from graytrack.client.routes import Call
from graytrack.wire import Calibration, Moved, Status

T = TypeVar("T")
FAILED = frozenset({"failed", "aborted", "interrupted"})
Progress = Callable[[float, str], None]
CALIBRATION_TIMEOUT_S = 900.0  # the closed loop on a slow host; the daemon's job goes on past it anyway
SETTLE_TIMEOUT_S = 60.0
SETTLE_TOLERANCE_MM = 0.001  # the grating within 1 µm of the target, and at rest
POLL_S = 0.1


@dataclass(frozen=True)
class Pause:
    seconds: float


Plan = Generator["Call[Any] | Pause", Any, T]


def calibrate(progress: Progress | None, timeout_s: float, poll_s: float) -> Plan[Calibration]:
    """Start a calibration and follow it to ``done``; ``progress(fraction, message)`` on every change."""
    job: Calibration = yield routes.start_calibration()
    return (yield from follow(job, progress, timeout_s, poll_s))


def follow(job: Calibration, progress: Progress | None, timeout_s: float, poll_s: float) -> Plan[Calibration]:
    """Follow the calibration ``job`` (as last read) to ``done``; ``CalibrationFailed`` when it ends otherwise."""
    deadline = time.monotonic() + timeout_s
    reported: tuple[float, str] | None = None
    while True:
        if progress is not None and (job.progress, job.message) != reported:
            reported = (job.progress, job.message)
            progress(*reported)
        if job.state == "done":
            return job
        if job.state in FAILED:
            raise CalibrationFailed(job)
        if time.monotonic() > deadline:
            raise WaitTimeout(f"calibration {job.id} still {job.state} after {timeout_s:g} s "
                              f"({job.progress:.0%}: {job.message}); it goes on in the daemon")
        yield Pause(poll_s)
        job = yield routes.calibration(job.id)


def calibrated(progress: Progress | None, timeout_s: float, poll_s: float) -> Plan[Status]:
    """Until the daemon has a model: follow the calibration it runs, else start one if it has none.

    A daemon that has just started (``make run``) is ``starting``, then calibrates itself on the
    virtual rig; starting a second calibration then would be refused (409), so this waits out the
    start and follows the daemon's own job instead. A daemon that begins its own between the status
    read and the request (409: one runs) is followed too. Returns the status once calibrated."""
    deadline = time.monotonic() + timeout_s
    status: Status = yield routes.status()
    while status.state == "starting" and time.monotonic() < deadline:
        yield Pause(poll_s)
        status = yield routes.status()
    job = status.calibration
    if job is not None and job.state not in FAILED | {"done"}:
        yield from follow((yield routes.calibration(job.id)), progress, timeout_s, poll_s)
    elif not status.calibrated:
        try:
            started: Calibration = yield routes.start_calibration()
        except Conflict:
            status = yield routes.status()
            job = status.calibration
            if job is None or job.state in FAILED | {"done"}:
                raise  # refused for another reason than a calibration under way
            started = yield routes.calibration(job.id)
        yield from follow(started, progress, timeout_s, poll_s)
    return (yield routes.status())


def settle(target_mm: float, tolerance_mm: float, timeout_s: float, poll_s: float) -> Plan[Status]:
    """Wait until the grating has come to rest within ``tolerance_mm`` of ``target_mm``."""
    deadline = time.monotonic() + timeout_s
    while True:
        status: Status = yield routes.status()
        grating = status.grating_mm
        if status.moving is False and grating is not None and abs(grating - target_mm) <= tolerance_mm:
            return status
        if status.state == "fault":
            raise NotReady(f"the stage did not reach {target_mm:g} mm: {status.reason}")
        if time.monotonic() > deadline:
            where = "unknown" if grating is None else f"{grating:.6g} mm"
            raise WaitTimeout(f"the stage did not settle at {target_mm:g} mm within {timeout_s:g} s "
                              f"(grating {where}, moving {status.moving})")
        yield Pause(poll_s)


def move(call: Call[Moved], wait: bool, tolerance_mm: float, timeout_s: float, poll_s: float) -> Plan[Moved]:
    """A move or jog; with ``wait``, also until the stage rests at the target the daemon answered."""
    moved: Moved = yield call
    if wait:
        yield from settle(moved.target_mm, tolerance_mm, timeout_s, poll_s)
    return moved


def run(plan: Plan[T], send: Callable[[Call[Any]], Any]) -> T:
    """Drive ``plan`` with blocking requests and sleeps."""
    try:
        step = next(plan)
        while True:
            if isinstance(step, Pause):
                time.sleep(step.seconds)
                step = plan.send(None)
            else:
                try:
                    answer = send(step)
                except GraytrackClientError as refused:  # the daemon's refusal is the plan's to handle or raise
                    step = plan.throw(refused)
                else:
                    step = plan.send(answer)
    except StopIteration as done:
        return done.value
    finally:
        plan.close()


async def run_async(plan: Plan[T], send: Callable[[Call[Any]], Awaitable[Any]]) -> T:
    """Drive ``plan`` on the running event loop."""
    try:
        step = next(plan)
        while True:
            if isinstance(step, Pause):
                await asyncio.sleep(step.seconds)
                step = plan.send(None)
            else:
                try:
                    answer = await send(step)
                except GraytrackClientError as refused:  # (as run)
                    step = plan.throw(refused)
                else:
                    step = plan.send(answer)
    except StopIteration as done:
        return done.value
    finally:
        plan.close()
