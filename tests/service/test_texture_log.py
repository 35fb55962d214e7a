"""The daemon's live tracker learns dust that lands on the print, and its event log says what was
learned, where and how sure; another model taking over (a rollback) drops it, and says so."""

from __future__ import annotations

import re

import numpy as np
import pytest

from graytrack.core.tracking import LiveTracker
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.daemon.texture_log import TextureLog
from tests.conftest import rig_model

pytestmark = pytest.mark.unit


def test_marks_learned_live_are_logged_and_dropped_with_their_model():
    model = rig_model("paper", "", seed=4, seconds=20.0)
    run, truth = build_rig("paper", "dust_settling", seed=4, run=1).record(10.0)
    events: list[tuple[str, str]] = []
    log = TextureLog(lambda kind, message: events.append((kind, message)))
    tracker = LiveTracker(model, x0_mm=float(run.reference[0]))
    placed = []
    for frame, reference in zip(run.frames, run.reference):
        fix = tracker.update(frame, float(reference))
        log.observe(tracker.state.texture)
        placed.append(fix.x_mm)
    error = (np.asarray(placed) - truth.x_mm) * 1e3
    assert np.isfinite(error).mean() >= 0.99
    learned = [message for kind, message in events if kind == "texture_learned"]
    assert len(learned) == sum(event.what == "learned" for event in tracker.state.texture.events) >= 8
    assert re.search(r"at x_w = \d+\.\d{3} mm .*% \+/- \d+\.\d % of the light, from \d+ frames", learned[0])
    before = len(events)
    log.observe(tracker.state.texture)  # nothing new: nothing logged twice
    assert len(events) == before
    log.replaced("calibration 7 installed")
    kind, message = events[-1]
    assert kind == "texture_dropped" and message.startswith(f"{len(tracker.state.texture.learned)} mark(s)")
    # the model installed anew starts from the print as calibrated
    assert LiveTracker(model).state.texture.learned == []
