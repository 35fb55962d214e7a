"""The band of shadow's own numerics (core/moving_band.py): its slopes, and what counts as motion."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.moving_band import BandAnswer, MovingBand, _moving, band, peak_depth


def test_the_slopes_are_the_bands_derivatives():
    """The solve's Jacobian by the edges and the softness: central differences agree to 1e-6."""
    columns = np.arange(100, dtype=np.float64)
    params = np.array([-12.3, 35.7, 14.2])
    value, *slopes = band(columns, *params)
    for i, slope in enumerate(slopes):
        step = np.zeros(3)
        step[i] = 1e-5
        numeric = (band(columns, *(params + step))[0] - band(columns, *(params - step))[0]) / 2e-5
        np.testing.assert_allclose(slope, numeric, atol=1e-6)
    assert value.max() == pytest.approx(0.5 * (1 + 1), abs=0.2)  # deep inside: the full depth's share


def test_motion_is_steady_travel_not_wander():
    """A band crossing at 6 px a frame has moved after one step; a light shape fixed to the camera,
    whose fitted edge wanders a pixel or two either way, has not, however long it is followed."""
    assert _moving(np.array([6.1]))
    assert not _moving(np.array([1.5]))
    assert not _moving(np.array([1.2, -0.8, 1.1, -1.3, 0.9]))
    assert _moving(np.array([-1.2, -1.1, -1.3]))  # a slow band, a pixel a frame


def _answer(left: float, right: float, depth: float, edge: float) -> BandAnswer:
    """A band's joint answer on its first frame, within its χ² limit, seen at 10 of its noise."""
    covariance = np.diag([1e-6, 1.0, 1.0, 1e-4, 1.0])
    return BandAnswer(np.array([1.0, left, right, depth, edge]), covariance, 1.0, 1600.0, 10.0, 0.5,
                      np.array([left, right]), np.eye(2))


def test_a_faint_broad_dip_is_no_band_whatever_its_nominal_depth():
    """Row banding on a 16-row strip, against the light held, was fitted as a band 4.9 % deep but 18 px
    wide and 44 px soft: 0.8 % at its middle. Taken for a shadow (the old rule read the nominal depth),
    its next frame's 10-50 px jump counted as motion and 7 frames of a steady run were flagged
    ``light``. A cable's shadow (48 px wide, 16 px soft, a fifth deep) reaches 0.87 of its depth."""
    assert peak_depth(110.1, 128.1, 0.049, 43.9) == pytest.approx(0.0079, abs=2e-4)
    assert peak_depth(20.0, 68.0, 0.2, 16.0) == pytest.approx(0.2 * 0.866, abs=2e-3)
    moving = MovingBand(16, 100)
    limit = 3.8
    assert not moving.sane(_answer(110.1, 128.1, 0.049, 43.9), 1e3, limit)
    assert not moving.sane(_answer(-44.7, -19.7, 0.04, 41.2), 1e3, limit)  # (its tail alone in view)
    assert moving.sane(_answer(20.0, 68.0, 0.2, 16.0), 1e3, limit)
    assert moving.sane(_answer(-35.8, -20.5, 0.99, 19.1), 1e3, limit)  # a strip's band, its tail in view, as solved
    assert moving.sane(_answer(-150.0, 60.0, 0.05, 5.0), 1e3, limit)  # a single edge (a hand): shallow, but a step
