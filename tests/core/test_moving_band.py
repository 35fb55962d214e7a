"""The band of shadow's own numerics (core/moving_band.py): its slopes, and what counts as motion."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.moving_band import _moving, band


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
