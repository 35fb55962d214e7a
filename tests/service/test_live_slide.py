"""The daemon on a rig without a grating (``[daemon] grating = false``) streaming a 16-row strip whose
lens warms up (its magnification ramps, the optical axis 300 px off the ROI: the image slides 28 µm
while no image can tell it from the stage): each streamed bound carries the slide a magnification
change could give the image (service/daemon/slide.py, core/slide.py), so no frame is 4+ bounds off
the truth without a flag; a steady stream flags nothing. Scored against the virtual rig's truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.estimator.mount import SHOWN_ACCELERATION, SHOWN_BEYOND
from graytrack.core.models.io import load_model
from graytrack.core.recording import acceleration_phases, load
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.drivers.config import ConfigError
from graytrack.service.daemon.settings import parse_settings
from graytrack.service.daemon.slide import LiveSlide
from tests.service.helpers import stream_through_daemon

RAMP = "magnification_drift:ppm=1500:ramp_s=6"


@pytest.fixture(scope="module")
def model():
    return calibrate(build_rig("strip16", "", seed=3).record(6.0)[0], "paper").model


def _scored(model, effects: str, slide: LiveSlide | None):
    """Streamed through the daemon's frame loop: (error µm, bound µm, flagged, messages, acquisition)."""
    run, truth = build_rig("strip16", effects, seed=3, run=1).record(6.0)
    # the recording's grating is handed in with every frame: the daemon without one drops the pairing itself
    messages, _, acquisition = stream_through_daemon(model, run, trim_enabled=False, slide=slide)
    fixes = [m for m in messages if m.get("x_mm") is not None and math.isfinite(m["x_mm"])]
    assert len(fixes) > 0.99 * truth.x_mm.size
    error = np.array([(m["x_mm"] - truth.x_mm[m["seq"] - 1]) * 1e3 for m in fixes])
    period_um = model.period_mm * 1e3
    error -= period_um * np.round(np.median(error) / period_um)  # the image alone: origin up to whole periods
    bound = np.array([m["crlb_um"] for m in fixes])
    flagged = np.array([bool(m["stale"]) for m in fixes])
    return error, bound, flagged, fixes, acquisition


def _silent(error, bound, flagged) -> float:
    return float(np.mean((np.abs(error) > 4.0 * bound) & ~flagged))


@pytest.mark.unit  # the daemon's frame loop on recorded frames
def test_a_warming_lens_streamed_without_a_grating_is_never_silently_off(model):
    """Before: the daemon's bound alone, the frames of the ramp before the watch's mean tells it 4+ bounds off."""
    error, bound, flagged, fixes, acquisition = _scored(model, RAMP, LiveSlide())
    assert _silent(error, bound, flagged) <= 0.005
    slide = np.array([m["slide_sigma_um"] for m in fixes])
    assert np.all(slide > 0) and np.all(bound >= slide)
    assert all("reference_mm" not in m and "error_um" not in m for m in fixes)  # no grating: none streamed
    status = acquisition.slide.status()
    assert status["axis_px"] == 300.0 and not status["declared"] and status["sigma_um"] > 0


@pytest.mark.unit  # the daemon's frame loop on recorded frames
def test_the_old_daemon_bound_alone_is_silently_off_on_the_ramp(model):
    """What the test above guards: the same stream with the grating's pairing dropped but no slide carried."""
    run, truth = build_rig("strip16", RAMP, seed=3, run=1).record(6.0)
    run.reference[:] = np.nan
    messages, _, _ = stream_through_daemon(model, run, trim_enabled=False)
    fixes = [m for m in messages if m.get("x_mm") is not None and math.isfinite(m["x_mm"])]
    error = np.array([(m["x_mm"] - truth.x_mm[m["seq"] - 1]) * 1e3 for m in fixes])
    period_um = model.period_mm * 1e3
    error -= period_um * np.round(np.median(error) / period_um)
    bound = np.array([m["crlb_um"] for m in fixes])
    assert _silent(error, bound, np.array([bool(m["stale"]) for m in fixes])) > 0.04


@pytest.mark.unit  # the daemon's frame loop on recorded frames
def test_a_steady_stream_without_a_grating_flags_nothing(model):
    error, bound, flagged, fixes, _ = _scored(model, "", LiveSlide())
    assert flagged.mean() < 0.01 and _silent(error, bound, flagged) <= 0.005
    late = np.array([m["slide_sigma_um"] for m in fixes[100:]])
    assert 0.5 < np.median(late) < 2.5  # ~60 ppm the frames cannot rule out, 300 px of lever


@pytest.mark.unit  # the daemon's frame loop on recorded frames
def test_an_axis_on_the_roi_carries_nothing(model):
    _, bound, _, fixes, _ = _scored(model, "", LiveSlide(axis_px=0.0))
    assert all(m["slide_sigma_um"] == 0.0 for m in fixes)


@pytest.mark.unit  # the daemon's frame loop on recorded frames
def test_a_knock_streamed_without_a_grating_is_flagged_from_the_frame_after(model):
    """``[daemon] stage_acceleration_mm_s2`` (the stage's ACC) reaches the estimator: a knock on the camera's
    mount (40 µm, 0.2°) streamed by the estimator engine without a grating is flagged `geometry` from the
    frame after it on, none 4+ bounds off the truth unflagged; without the declared acceleration (the
    estimator's default, 1000 mm/s²: 300 µm allowed at 50 frames/s) the frames after the knock are 40 µm off."""
    run, truth = build_rig("strip16", "knock:um=40:deg=0.2:at_s=2", seed=3, run=1).record(4.0)
    knocked = int(np.searchsorted(run.t, 2.0))
    for acceleration in (100.0, None):
        messages, _, acquisition = stream_through_daemon(model, run, False, slide=LiveSlide(None, acceleration),
                                                         engine="estimator")
        estimator = acquisition.tracker.estimator
        assert estimator.mount.acceleration >= (acceleration or 1000.0)
        error = np.array([(m["x_mm"] - truth.x_mm[m["seq"] - 1]) * 1e3 for m in messages])
        error -= model.period_mm * 1e3 * np.round(np.median(error[:knocked]) / (model.period_mm * 1e3))
        bound = np.array([m["crlb_um"] for m in messages])
        flagged = np.array([bool(m["stale"]) for m in messages])
        reasons = [m["stale_reason"] for m in messages]
        after = slice(knocked + 2, None)
        # the slide the estimator's bound states, streamed and in the status as the slide watch's is
        slide = np.array([m["slide_sigma_um"] for m in messages])
        assert np.all(slide > 0) and np.all(bound >= slide)
        assert acquisition.slide.status()["sigma_um"] == pytest.approx(slide[-1])
        if acceleration is not None:
            assert np.all(flagged[after]) and set(reasons[after]) == {"geometry"}
            assert np.sum((np.abs(error) > 4.0 * bound) & ~flagged) <= 1  # the knock's own frame at most
            assert np.all(np.abs(error[after]) < 4.0 * bound[after])
        else:
            assert np.median(np.abs(error[after])) > 30.0


@pytest.mark.unit
def test_the_config_declares_the_rig_without_a_grating():
    daemon = parse_settings({"daemon": {"grating": False, "axis_px": 120}}).daemon
    assert daemon.grating is False and daemon.axis_px == 120
    assert parse_settings({}).daemon.grating is True and parse_settings({}).daemon.axis_px is None
    with pytest.raises(ConfigError, match="trim = true needs a grating"):
        parse_settings({"daemon": {"grating": False, "trim": True}})
    with pytest.raises(ConfigError, match="axis_px"):
        parse_settings({"daemon": {"grating": False, "axis_px": -5}})
    assert parse_settings({"daemon": {"grating": False, "stage_acceleration_mm_s2": 50}}).daemon \
        .stage_acceleration_mm_s2 == 50
    with pytest.raises(ConfigError, match="stage_acceleration_mm_s2"):
        parse_settings({"daemon": {"stage_acceleration_mm_s2": 0}})


def test_the_running_daemon_without_a_grating_streams_and_shows_the_slide(tmp_path):  # system (tests/conftest.py)
    """The whole daemon (virtual rig, calibrated at start) configured ``grating = false``, ``axis_px = 150``:
    its messages carry the slide, unpaired, and /api/status shows it."""
    import json

    from websockets.sync.client import connect

    from graytrack.service.daemon.app import create_app
    from tests.service.helpers import LiveServer, fast_settings, wait_for

    with LiveServer(create_app(fast_settings(tmp_path, grating=False, axis_px=150.0))) as rig:
        rig.wait_state("tracking")
        with connect(f"ws://127.0.0.1:{rig.port}/ws/position", open_timeout=5) as ws:
            messages = [json.loads(ws.recv(timeout=5)) for _ in range(20)]
        status = wait_for(lambda: (doc := rig.status())["slide"]["sigma_um"] is not None and doc, 10.0, "the slide")
    assert all(m["slide_sigma_um"] > 0 and m["crlb_um"] >= m["slide_sigma_um"] for m in messages)
    assert all("reference_mm" not in m for m in messages)
    assert status["slide"]["axis_px"] == 150.0 and status["slide"]["declared"]
    # every move of the sweep was commanded through the daemon: its recording states them (service/daemon/motion.py)
    # and the calibration learned from them what the stage does beyond its commands (core/estimator/mount.py)
    assert status["slide"]["stage_commands_known"]
    (folder,) = {path.parent for path in tmp_path.rglob("recording.npz")}
    recording = load(folder / "recording.npz")
    phases = acceleration_phases(recording.meta)
    assert phases is not None and len(phases) >= 2  # a move to each stop
    assert np.all(phases[:, 0] <= recording.t[-1]) and np.all(phases[:, 1] >= recording.t[0])
    # the stops' frames are exposed at rest; a phase ends where the readings confirm the rest (a few polls late,
    # never early), so only a stop's first frames may still fall inside it
    inside = np.mean([np.any((phases[:, 0] < t) & (t < phases[:, 1])) for t in recording.t])
    assert inside < 0.25, inside
    info = load_model(folder / "model.json").info
    assert 0.0 <= info[SHOWN_BEYOND] < info[SHOWN_ACCELERATION]
