"""``ensure_calibrated``'s plan against a scripted daemon: it follows the calibration the daemon runs
(``make run``'s first start) instead of starting a second one (409), and starts one only when none
runs and there is no model. Pure: the plan is driven with canned answers and no pauses."""

from __future__ import annotations

from typing import Any

import pytest

from graytrack.client import plans
from graytrack.client.errors import Conflict
from graytrack.client.routes import Call
from graytrack.wire import Calibration, CalibrationStarted, JobSummary, Status

pytestmark = pytest.mark.unit

NO_FRAME = dict(position_mm=None, locked=None, crlb_um=None, stale=True, age_ms=None, grating_mm=None, moving=None,
                target_mm=None, velocity_mm_s=None, reason=None, faults={}, model=None, limits_mm=None,
                frame_rate_hz=0.0, frames=0, dropped=0, active_calibration=None, simulated=True, uptime_s=1.0,
                version="test")


def status(state: str, calibrated: bool, job: tuple[str, float] | None = None) -> Status:
    summary = None if job is None else JobSummary(id="c1", state=job[0], progress=job[1], message=job[0])
    return Status(state=state, calibrated=calibrated, calibration=summary, **NO_FRAME)


def job(state: str, progress: float) -> dict[str, Any]:
    return dict(id="c1", model="paper", positions=10, frames_per_position=5, state=state, progress=progress,
                message=state, started="2026-11-27T00:00:00Z")


class Daemon:
    """Answers each call from its script (one list per route), recording what was sent."""

    def __init__(self, statuses: list[Status], jobs: list[dict[str, Any]]) -> None:
        self.statuses, self.jobs, self.sent = statuses, jobs, []

    def __call__(self, call: Call[Any]) -> Any:
        self.sent.append(f"{call.method} {call.path}")
        if call.path == "/api/status":
            return self.statuses.pop(0)
        if call.method == "POST":
            return CalibrationStarted(url="/api/calibration/c1", **self.jobs.pop(0))
        return Calibration(**self.jobs.pop(0))


def ensure(daemon: Daemon) -> tuple[Status, list[tuple[float, str]]]:
    reports: list[tuple[float, str]] = []
    done = plans.run(plans.calibrated(lambda *report: reports.append(report), timeout_s=60.0, poll_s=0.0), daemon)
    return done, reports


def test_a_starting_daemon_is_waited_for_and_its_own_calibration_followed() -> None:
    daemon = Daemon([status("starting", False), status("calibrating", False, ("sweeping", 0.25)),
                     status("tracking", True, ("done", 1.0))],
                    [job("sweeping", 0.5), job("fitting", 0.8), job("done", 1.0)])
    done, reports = ensure(daemon)
    assert "POST /api/calibration" not in daemon.sent, "no second calibration (the daemon would answer 409)"
    assert daemon.sent == ["GET /api/status"] * 2 + ["GET /api/calibration/c1"] * 3 + ["GET /api/status"]
    assert reports == [(0.5, "sweeping"), (0.8, "fitting"), (1.0, "done")]
    assert done.state == "tracking" and done.calibrated


def test_without_a_model_or_a_running_job_one_is_started() -> None:
    daemon = Daemon([status("idle", False, ("failed", 0.3)), status("tracking", True, ("done", 1.0))],
                    [job("queued", 0.0), job("done", 1.0)])
    done, reports = ensure(daemon)
    assert daemon.sent == ["GET /api/status", "POST /api/calibration", "GET /api/calibration/c1", "GET /api/status"]
    assert reports == [(0.0, "queued"), (1.0, "done")] and done.calibrated


def test_a_calibrated_daemon_is_left_alone() -> None:
    daemon = Daemon([status("tracking", True, ("done", 1.0)), status("tracking", True, ("done", 1.0))], [])
    done, reports = ensure(daemon)
    assert daemon.sent == ["GET /api/status"] * 2 and reports == [] and done.calibrated


class Racing(Daemon):
    """A daemon that begins its own calibration between the status read and the client's request."""

    def __call__(self, call: Call[Any]) -> Any:
        if call.method == "POST":
            self.sent.append(f"{call.method} {call.path}")
            raise Conflict("POST /api/calibration: 409 calibration c1 is already running")
        return super().__call__(call)


def test_a_calibration_the_daemon_began_meanwhile_is_followed_not_refused() -> None:
    daemon = Racing([status("idle", False), status("calibrating", False, ("sweeping", 0.1)),
                     status("tracking", True, ("done", 1.0))],
                    [job("sweeping", 0.2), job("done", 1.0)])
    done, reports = ensure(daemon)
    assert daemon.sent == ["GET /api/status", "POST /api/calibration", "GET /api/status",
                           "GET /api/calibration/c1", "GET /api/calibration/c1", "GET /api/status"]
    assert reports == [(0.2, "sweeping"), (1.0, "done")] and done.calibrated


def test_a_refusal_with_no_calibration_under_way_is_raised() -> None:
    daemon = Racing([status("idle", False), status("idle", False, ("failed", 0.3))], [])
    with pytest.raises(Conflict):
        ensure(daemon)
    assert daemon.sent == ["GET /api/status", "POST /api/calibration", "GET /api/status"]


def test_the_asyncio_driver_hands_a_refusal_to_the_plan_too() -> None:
    import asyncio

    daemon = Racing([status("idle", False), status("calibrating", False, ("sweeping", 0.1)),
                     status("tracking", True, ("done", 1.0))],
                    [job("done", 1.0)])

    async def send(call: Call[Any]) -> Any:
        return daemon(call)

    done = asyncio.run(plans.run_async(plans.calibrated(None, timeout_s=60.0, poll_s=0.0), send))
    assert done.calibrated and daemon.sent.count("POST /api/calibration") == 1
