"""The status document from a snapshot built by hand: the state's precedence, figures withdrawn
once stale, and a document the API's Status model accepts field for field."""

from __future__ import annotations

from dataclasses import replace

import pytest

from graytrack.service.daemon.snapshot import Counters, Devices, FrameLoop, Grating, RigSnapshot
from graytrack.service.daemon.status import document
from graytrack.wire import Status

pytestmark = pytest.mark.unit
MESSAGE = {"seq": 41, "t": 12.5, "x_mm": 5.25, "locked": True, "crlb_um": 1.5, "gain": 1.01, "offset_gray": -0.2,
           "chi2": 1.04, "rejected_px": 2, "transient_px": 0, "focus_px2": None, "focus_sigma_px2": None,
           "stale": False, "stale_reason": None, "texture_px": 0}
LOOP = FrameLoop(last_message=MESSAGE, seconds_since_tracked=0.25, frame_rate_hz=49.996, tracker_ready=True,
                 model_stale=None, counters=Counters(frames=120, tracked=118, unplaced=1, lock_events=0,
                                                     camera_errors=0, tracking_errors=0, dropped=3),
                 crashes=0, trim={"enabled": False})
TRACKING = RigSnapshot(
    closing=False, faults={}, faults_raised=0, devices=Devices((0.0, 10.0), camera_dropped=0, stage_reconnects=0),
    frame_loop=LOOP, grating=Grating(fresh_mm=5.2501, silent_s=0.0125, moving=False, reads=40, errors=0, crashes=0),
    model="paper model, 5 harmonics", job=None, job_active=False,
    active_calibration={"id": "c1", "finished": "2026-11-23T00:00:00+00:00", "model": "paper model, 5 harmonics",
                        "error_std_um": 1.9, "bound_um": 1.6},
    target_mm=5.25, velocity_mm_s=20.0, calibrations_finished={"done": 1}, simulated=True, stale_after_s=1.0,
    uptime_s=12.3456)


def test_a_fresh_frame_shows_its_figures_and_the_document_is_what_the_status_model_describes() -> None:
    status = document(TRACKING)
    assert Status.model_validate(status).model_dump(mode="json") == status
    assert (status["state"], status["position_mm"], status["locked"],
            status["crlb_um"]) == ("tracking", 5.25, True, 1.5)
    assert status["fit"] == {"gain": 1.01, "offset_gray": -0.2, "chi2": 1.04, "rejected_px": 2, "transient_px": 0,
                             "focus_px2": None, "focus_sigma_px2": None, "stale": False, "stale_reason": None,
                             "texture_px": 0}
    assert (status["stale"], status["age_ms"], status["grating_age_ms"]) == (False, 250.0, 12.5)
    assert (status["frame_rate_hz"], status["frames"], status["dropped"], status["uptime_s"]) == (50.0, 120, 3, 12.346)
    assert status["limits_mm"] == [0.0, 10.0] and status["active_calibration"]["id"] == "c1"
    assert TRACKING.tracking_fresh


def test_a_frame_older_than_stale_after_s_is_withdrawn_not_shown_frozen() -> None:
    stale = replace(TRACKING, frame_loop=replace(LOOP, seconds_since_tracked=1.5))
    status = document(stale)
    assert (status["position_mm"], status["locked"], status["crlb_um"], status["fit"]) == (None, None, None, None)
    assert (status["stale"], status["age_ms"]) == (True, 1500.0)
    assert not stale.tracking_fresh and stale.state == "tracking", "the state is the rig's; health says it is stale"


@pytest.mark.parametrize(("changes", "state"), [
    ({"closing": True, "faults": {"camera": "no frame for 2.0 s"}}, "stopping"),
    ({"faults": {"camera": "no frame for 2.0 s"}, "job_active": True}, "fault"),
    ({"frame_loop": None, "job_active": True}, "starting"),
    ({"job_active": True}, "calibrating"),
    ({"model": None}, "idle"),
    ({}, "tracking"),
])
def test_the_state_is_stopping_then_fault_starting_calibrating_tracking_idle(changes: dict, state: str) -> None:
    assert replace(TRACKING, **changes).state == state


def test_faults_are_one_sentence_and_a_stale_model_names_its_family() -> None:
    snapshot = replace(TRACKING, faults={"camera": "no frame for 2.0 s", "stage": "POS? timed out"},
                       frame_loop=replace(LOOP, model_stale="light"))
    status = document(snapshot)
    assert status["reason"] == "camera: no frame for 2.0 s; stage: POS? timed out."
    assert (status["model_stale"], status["stale_reason"], snapshot.tracking_fresh) == (True, "light", False)
    assert document(replace(snapshot, model=None))["stale_reason"] is None, "no model, nothing to be stale"


def test_the_slide_a_rig_without_a_grating_carries_is_shown_and_null_with_one() -> None:
    slide = {"axis_px": 300.0, "declared": False, "lever_mm": 0.81, "sigma_um": 1.2, "stretch_ppm": 60.0}
    status = document(replace(TRACKING, frame_loop=replace(LOOP, slide=slide)))
    assert Status.model_validate(status).model_dump(mode="json") == status and status["slide"] == slide
    assert document(TRACKING)["slide"] is None
