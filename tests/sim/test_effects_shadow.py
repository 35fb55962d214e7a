"""A cable's shadow sweeping across the field (drivers/sim/shadow.py): its physical signature.

It darkens the lamp's light by up to ``depth`` in a soft-edged band; the band is fixed to neither
the print (it stays put while the stage moves) nor the camera (it crosses the pixels from pass to
pass, back and forth), and it is out of view between passes."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.drivers.sim.effects import EffectError
from graytrack.drivers.sim.scenarios import list_effects

from .helpers import light, quiet_rig

SHADOW = "moving_shadow:depth=0.3:width_mm=2:edge_mm=0.3:pass_s=1:passes=2:period_s=3:start_s=1"


def _gain(t_s: float, x_mm: float = 3.0) -> np.ndarray:
    """The light's gain across the line at one instant, the stage at ``x_mm``."""
    return light(quiet_rig(effects=[SHADOW]), [x_mm], [t_s])[0, 0] / light(quiet_rig(), [x_mm], [t_s])[0, 0]


def test_listed_as_an_illumination_effect():
    assert "moving_shadow" in list_effects()


def test_out_of_view_before_between_and_after_the_passes():
    for t in (0.0, 0.99, 2.01, 3.99, 5.01, 9.0):
        np.testing.assert_allclose(_gain(t), 1.0, atol=1e-9)


def test_a_soft_edged_band_depth_deep_crosses_the_pixels():
    mid = _gain(1.5)  # halfway through the first pass: the band is over the field's middle
    assert mid.min() == pytest.approx(0.7, abs=1e-3)  # the core loses the depth
    assert mid[0] > 0.99 and mid[-1] > 0.99  # 2 mm of a 6.2 mm field: its ends are lit
    centres = [int(np.argmin(_gain(t))) for t in (1.35, 1.5, 1.65)]
    assert centres[0] < centres[1] < centres[2]  # the first pass runs towards larger u ...
    back = [int(np.argmin(_gain(t))) for t in (4.35, 4.5, 4.65)]
    assert back[0] > back[1] > back[2]  # ... and the second swings back
    edge = mid[: int(np.argmin(mid))]
    assert np.all(np.diff(edge) <= 1e-12) and np.count_nonzero((edge < 0.99) & (edge > 0.71)) >= 5  # soft


def test_fixed_to_neither_the_print_nor_the_camera():
    """The stage moved 1 mm between two renders at the same instant: the shadow stays on the same
    pixels (not on the print); at another instant it is on other pixels (not on the camera)."""
    np.testing.assert_allclose(_gain(1.5, 2.0), _gain(1.5, 3.0), atol=1e-9)
    assert np.argmin(_gain(1.4)) != np.argmin(_gain(1.6))


def test_bad_parameters_are_refused():
    for spec in ("moving_shadow:depth=1", "moving_shadow:pass_s=0", "moving_shadow:period_s=0.5",
                 "moving_shadow:edge_mm=-1"):
        with pytest.raises(EffectError):
            quiet_rig(effects=[spec])
