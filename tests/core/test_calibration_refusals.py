"""Calibration refuses data that cannot determine a model, with a message that says why."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.errors import CalibrationError
from graytrack.core.recording import Recording
from tests.conftest import paper_recording


def test_no_reference():
    rec = paper_recording(n_frames=100)
    rec.reference[:] = np.nan
    with pytest.raises(CalibrationError, match="no reference"):
        calibrate(rec)


def test_stroke_shorter_than_a_period():
    rec = paper_recording(n_frames=200)
    short = rec.subset(slice(0, 100))  # 5.2 mm of an 8.6 mm period
    with pytest.raises(CalibrationError, match="shorter than one target period"):
        calibrate(short)
    blind = Recording(short.frames, short.t, short.reference, {})
    with pytest.raises(CalibrationError, match="period"):
        calibrate(blind)


def test_flat_frames():
    rec = paper_recording(n_frames=100)
    flat = Recording(np.full_like(rec.frames, 120.0), rec.t, rec.reference, rec.meta)
    with pytest.raises(CalibrationError, match="flat"):
        calibrate(flat)


def test_unknown_model_kind():
    with pytest.raises(CalibrationError, match="unknown model kind"):
        calibrate(paper_recording(n_frames=100), "spline")
