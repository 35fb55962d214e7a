"""The daemon with ``[daemon] trim`` streaming a 16-row strip whose lens's magnification goes through
a temperature cycle: the stretch is followed and taken out of each frame (core/stretch_follow.py)
by the tracker the daemon builds, its positions are at their bound and not flagged, and
``/api/status`` shows the stretch followed."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.drivers.sim.scenarios import build_rig
from tests.service.helpers import stream_through_daemon

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def streamed():
    calibration, _ = build_rig("strip16", "", seed=3).record(6.0)
    model = calibrate(calibration, "paper").model
    run, truth = build_rig("strip16", "magnification_drift:ppm=1500:cycle_s=4", seed=3, run=1).record(6.0)
    messages, _, acquisition = stream_through_daemon(model, run, trim_enabled=True)
    return messages, truth, acquisition.trim


def test_the_daemon_streams_a_magnification_cycle_at_its_bound_unflagged(streamed):
    """Before: 91 % of the streamed frames flagged `magnification`, the positions 2x their bound."""
    messages, truth, _ = streamed
    fixes = [m for m in messages if "x_mm" in m and np.isfinite(m["x_mm"])]
    assert len(fixes) > 0.99 * truth.x_mm.size
    error_um = np.array([(m["x_mm"] - truth.x_mm[m["seq"] - 1]) * 1e3 for m in fixes])
    bound_um = np.array([m["crlb_um"] for m in fixes])
    stale = np.array([bool(m["stale"]) for m in fixes])
    assert np.std(error_um) < 1.3 * np.sqrt(np.mean(bound_um ** 2))
    assert stale.mean() < 0.05
    assert np.sum((np.abs(error_um) > 4.0 * bound_um) & ~stale) <= 0.005 * len(fixes)  # never silently wrong


def test_the_status_shows_the_stretch_followed(streamed):
    _, _, trim = streamed
    stretch = trim.status()["stretch"]
    assert stretch["frames_corrected"] > 100 and stretch["followed_ppm"] is not None
