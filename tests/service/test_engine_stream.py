"""``[daemon] engine = "estimator"``: the daemon's frame loop driven by the one recursive estimator
(core/estimator/), streamed as the watches' path is, scored against the rig's truth."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.estimator import EstimatorSettings
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.daemon.settings import DaemonConfig
from tests.service.helpers import stream_through_daemon

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def paper():
    calibration, _ = build_rig("paper", "", seed=12).record(8.0)
    return calibrate(calibration, "paper").model


@pytest.mark.parametrize("trim", [False, True])
def test_the_daemon_streams_the_estimators_positions_within_their_bounds(paper, trim):
    run, truth = build_rig("paper", "light_change:gain=0.85:ambient_gray=8:start_s=2", seed=12, run=2).record(5.0)
    messages, _, acquisition = stream_through_daemon(paper, run, trim_enabled=trim, engine="estimator")
    assert acquisition.engine == "estimator"
    placed = [m for m in messages if m.get("x_mm") is not None]
    assert len(placed) == run.n_frames
    error = np.array([(m["x_mm"] - truth.x_mm[m["seq"] - 1]) * 1e3 for m in placed])
    bound = np.array([m["crlb_um"] for m in placed])
    assert np.sqrt(np.mean((error / bound) ** 2)) < 1.5
    stale = np.array([m["stale"] for m in placed])
    assert not np.any((np.abs(error) > 4 * bound) & ~stale)  # never silently wrong
    assert stale.mean() < 0.05
    # the light switched at 2 s is followed: the stream's gain ends at the rig's
    assert placed[-1]["gain"] == pytest.approx(0.85, abs=0.03)


def test_a_fused_stream_carries_the_clocks_rate_only_for_a_camera_on_its_own_clock(paper):
    """The daemon hands the estimator what its rig states of itself: the virtual camera is triggered on the clock
    that latches the grating, and a steady fused stream's bound is then the grating's and the latch's (rms pull
    within 0.8-1.25); said to run free, the bound carries the two clocks' rate apart as well."""
    from graytrack.core.recording import CAMERA_TRIGGER

    run, truth = build_rig("paper", "", seed=12, run=3).record(10.0)
    pulls = {}
    for trigger in ("hardware", "free-run"):
        messages, _, acquisition = stream_through_daemon(paper, run, trim_enabled=True, engine="estimator",
                                                         rig_meta={**run.meta, CAMERA_TRIGGER: trigger})
        free = EstimatorSettings().clock_drift_prior
        assert acquisition.estimator_settings.clock_drift_prior == (0.0 if trigger == "hardware" else free)
        placed = [m for m in messages if m.get("x_mm") is not None]
        error = np.array([(m["x_mm"] - truth.x_mm[m["seq"] - 1]) * 1e3 for m in placed])
        bound = np.array([m["crlb_um"] for m in placed])
        assert sum(m["stale"] for m in placed) < 0.01 * len(placed)
        pulls[trigger] = np.sqrt(np.mean((error / bound) ** 2))
    assert 0.8 <= pulls["hardware"] <= 1.25, pulls
    assert pulls["free-run"] < pulls["hardware"], pulls


def test_the_engine_is_a_declared_setting():
    assert DaemonConfig().engine == "watches"
    assert DaemonConfig(engine="estimator").engine == "estimator"
    with pytest.raises(ValueError):
        DaemonConfig(engine="kalman")


def test_the_lamps_mains_is_a_declared_setting_written_into_the_daemons_recordings(tmp_path):
    """``[daemon] mains_hz``: the mains the rig's lamp runs on, whose flicker at twice it the estimator follows. The
    daemon states it in every recording it makes (its calibration sweep's too), and a frame loop hands it to the
    estimator with the rest of what the rig states of itself."""
    from fastapi.testclient import TestClient

    from graytrack.core.recording import MAINS_HZ, load
    from graytrack.service.daemon.app import create_app
    from tests.service.helpers import fast_settings, wait_state

    assert DaemonConfig().mains_hz is None and DaemonConfig(mains_hz=60).mains_hz == 60.0
    with pytest.raises(ValueError):
        DaemonConfig(mains_hz=-50)
    app = create_app(fast_settings(tmp_path, engine="estimator", mains_hz=60.0))
    with TestClient(app) as client:
        wait_state(client, "tracking", 30.0)
        latest = client.get("/api/calibration/latest").json()
        assert load(latest["files"]["recording"]).meta[MAINS_HZ] == 60.0
        assert app.state.rig.acquisition.estimator_settings.mains_hz == 60.0
