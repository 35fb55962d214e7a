"""The calibration's χ² level when its own light moved (core/light_level.py): a seed model fitted
under a hunting gain states the level its frames show with the light solved, as the tracker
solves it, so a run's first frames whose light is off ask for the light instead of being placed
several bounds off under the fit's own level (57× the noise), unflagged."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.light_level import ask_ratio, stated_level
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig

HUNTING = "gain_hunting:depth=0.05"


def test_the_light_solved_level_is_stated_only_where_the_light_explains_the_fit_s_misfit():
    assert ask_ratio(100) == pytest.approx(1.0 + 5.0 * np.sqrt(0.02))
    assert stated_level(57.5, 1.01, 100) == 1.01  # the hunting gain's steps: the tracker solves them
    assert stated_level(1.028, 1.004, 100) == 1.028  # a steady rig: two unknowns fewer, kept as fitted
    assert stated_level(11.2, 10.9, 100) == 11.2  # scratches the model lacks: no light explains them
    assert stated_level(3.0, float("nan"), 100) == 3.0


@pytest.fixture(scope="module")
def hunted():
    """The seed model calibrated while the gain hunted, and a later run of the same rig with its truth."""
    calibration, _ = build_rig("paper", HUNTING, seed=3).record(20.0)
    run, truth = build_rig("paper", HUNTING, seed=3, run=1).record(2.0)
    return calibrate(calibration, "paper").model, run, truth


def test_a_seed_model_calibrated_under_a_hunting_gain_places_no_first_frame_far_off_unflagged(hunted):
    """Until 2026-11-27 the model's level was the fit's, 57× the noise: the run's frames 4-6 (χ² 48-89,
    the gain 5 % off) stayed under the single-frame limit (98×), the light held, 4.4-5.3 bounds off
    the truth with no flag. With the light-solved level (1.01) they ask for the light at once."""
    model, run, truth = hunted
    assert model.info["calibration_chi2"] < 1.1
    result = track(model, run, light="auto", robust=True)
    pull = (result.x_mm - truth.x_mm) / result.crlb_mm
    silent = np.isfinite(pull) & (np.abs(pull) > 4.0) & ~result.stale
    assert silent.sum() == 0, np.flatnonzero(silent)
    assert (result.gain[:10] != 1.0).all()  # the light solved from the first frames
    assert result.stale.mean() < 0.01
