"""The daemon without ``[daemon] trim`` streaming a lens ramp whose optical axis is far off the ROI: the
slide takes the camera more than 100 bounds off the grating, and the stream names it ``magnification``,
as ``track`` does (the scale watch it builds carries the far-off judgement: core/watches/scale.py), where
the far-off watch alone had named it a model of another period or pitch (``scale``)."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.drivers.sim.scenarios import build_rig
from tests.service.helpers import stream_through_daemon

pytestmark = pytest.mark.unit


def test_the_daemon_streams_a_far_lens_slide_named_magnification():
    calibration, _ = build_rig("paper", "", seed=11).record(8.0)
    model = calibrate(calibration, "paper").model
    run, _ = build_rig("paper", "magnification_drift:ppm=3000:axis_px=-1000:ramp_s=6", seed=11, run=4).record(6.0)
    messages, _, _ = stream_through_daemon(model, run, trim_enabled=False)
    fixes = [m for m in messages if m.get("x_mm") is not None and np.isfinite(m["x_mm"])]
    assert len(fixes) > 0.99 * run.n_frames
    far = [m for m in fixes if abs(m["error_um"]) > 100.0 * m["crlb_um"]]
    assert len(far) > 60  # the run's last ~85 frames
    named = collections.Counter(m["stale_reason"] if m["stale"] else None for m in far)
    assert named == {"magnification": len(far)}, named
