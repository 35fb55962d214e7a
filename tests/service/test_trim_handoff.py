"""The daemon hands its scale watch, with the trim, to the tracker through its constructor: one
monitor, so the stale flag and the bound of what is streamed follow the trim in force.

Before, ``ReferenceTrim.install`` set ``tracker.scale_watch`` after ``LiveTracker`` had built its
validity monitor: the daemon ran two monitors on the same frames, and the stream's flag came from
the one that knew no trim, while its bound was the untrimmed frame's."""

from __future__ import annotations


import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.daemon.acquisition import Acquisition
from tests.service.helpers import stream_through_daemon

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def grown():
    """A paper-rig model, and a later run of the rig whose print grew 400 ppm (the trim's evidence)."""
    calibration, _ = build_rig("paper", "", seed=7).record(8.0)
    run, truth = build_rig("paper", "target_growth:ppm=400", seed=7, run=1).record(8.0)
    return calibrate(calibration, "paper").model, run, truth


def _stream(model, run, enabled: bool) -> tuple[list[dict], list[tuple[str, str]], Acquisition]:
    """Every frame of ``run`` through the daemon's frame loop: the published messages and the events."""
    return stream_through_daemon(model, run, enabled)


def test_the_daemons_flag_and_bound_follow_the_trim_in_force(grown):
    model, run, truth = grown
    messages, events, acquisition = _stream(model, run, enabled=True)
    kinds = [kind for kind, _ in events]
    assert "trim_applied" in kinds
    watches = [w for w in acquisition.tracker.state.monitor.watches if type(w).__name__ == "ScaleWatch"]
    assert len(watches) == 1 and watches[0].trimmer is not None  # one monitor of camera against grating
    trimmed = [m for m in messages if "trim_um" in m]
    assert len(trimmed) > run.n_frames // 2
    # the bound streamed is the trimmed position's: the frame's own with the trim's σ and lag added
    assert all(m["crlb_um"] >= m["trim_sigma_um"] > 0 for m in trimmed)
    # once trimmed, the flag is the trim's: the camera agrees with the grating again (the watch that
    # knew no trim had flagged `scale` on every one of these frames)
    assert sum(m["stale"] for m in trimmed) < 0.05 * len(trimmed)
    truth_mm = dict(zip(range(run.n_frames), truth.x_mm))
    pulls = [abs(m["x_mm"] - truth_mm[m["seq"] - 1]) * 1e3 / m["crlb_um"] for m in trimmed if not m["stale"]]
    assert np.mean(np.array(pulls) > 4.0) < 0.005  # never silently wrong


def test_without_the_trim_the_same_drift_is_flagged_scale(grown):
    model, run, _ = grown
    messages, events, _ = _stream(model, run, enabled=False)
    assert "scale_drift" in [kind for kind, _ in events] and not any("trim_um" in m for m in messages)
    late = messages[len(messages) // 2:]
    assert sum(m.get("stale_reason") == "scale" for m in late) > 0.9 * len(late)
