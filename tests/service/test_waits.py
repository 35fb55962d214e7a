"""The system tests' waits say where things were when time ran out, not only that it did."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from tests.service.helpers import wait_for, wait_job


class Reply:
    def __init__(self, document: dict[str, Any]) -> None:
        self.document = document

    def json(self) -> dict[str, Any]:
        return self.document


def test_a_wait_that_times_out_reports_the_last_value_or_what_show_gives() -> None:
    seen = iter(range(1, 1_000_000))
    with pytest.raises(AssertionError, match=r"^timed out after 0.05 s waiting for a count; last seen: \[\]$"):
        wait_for(lambda: [] if next(seen) else None, 0.05, "a count")
    with pytest.raises(AssertionError, match=r"waiting for a count; last seen: \{'count': \d+\}$"):
        wait_for(lambda: next(seen) < 0, 0.05, "a count", show=lambda: {"count": next(seen)})


def test_a_job_wait_reports_the_jobs_state_progress_and_message() -> None:
    job = {"id": "j1", "state": "sweeping", "progress": 0.4, "message": "stop 9/21 at 4.000 mm", "error": None,
           "report": {"large": "not shown"}}
    with pytest.raises(AssertionError) as timeout:
        wait_job(lambda path: Reply(job), "j1", ("done", "failed"), 0.05)
    assert str(timeout.value) == ("timed out after 0.05 s waiting for calibration j1 to be done or failed; last seen: "
                                  "{'id': 'j1', 'state': 'sweeping', 'progress': 0.4, "
                                  "'message': 'stop 9/21 at 4.000 mm', 'error': None}")
    assert wait_job(lambda path: Reply({**job, "state": "done"}), "j1", timeout_s=0.05)["state"] == "done"


def test_a_job_wait_on_a_daemon_that_does_not_answer_says_so() -> None:
    def refused(path: str) -> Reply:
        raise httpx.ConnectError("connection refused")

    with pytest.raises(AssertionError, match=r"waiting for calibration j2 to be done; last seen: 'no answer'$"):
        wait_job(refused, "j2", timeout_s=0.05)
