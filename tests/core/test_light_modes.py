"""The light's two modes (core/estimator/light_modes.py): a frame's reading of the light weighed under holding and
drifting, the drifting mode's probability carried from frame to frame and deciding the next frame's mode."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core.estimator.light_modes import LightModes

DT = 0.02  # s: a frame at 50 frames/s
HOLDING, MOVING = (1e-12, 1e-8), (0.005 ** 2, 0.1 ** 2)  # the modes' (gain, offset) variances per second
GAIN, OFFSET = 0, 1  # the light's states in the 2 × 2 covariances below


def _frame(modes: LightModes, gain_sigmas: float) -> None:
    """A frame read the light ``gain_sigmas`` of the holding mode's predicted spread of its reading away (the offset
    where it was): the prior a light the frames before found (the gain to 1e-4, the offset to 0.01 gray), in the
    frame's mode; the frame told as much again."""
    extra = np.diag([(MOVING[0] - HOLDING[0]) * DT, (MOVING[1] - HOLDING[1]) * DT]) if modes.drifting else 0.0
    prior = np.diag([1e-8, 1e-4]) + extra
    posterior = np.linalg.inv(np.linalg.inv(prior) + np.linalg.inv(np.diag([1e-8, 1e-4])))
    spread = math.sqrt(2e-8)  # the holding mode's: the prior's and the reading's variances
    moved = posterior @ np.linalg.solve(np.diag([1e-8, 1e-4]), np.array([gain_sigmas * spread, 0.0]))
    modes.weigh(prior, posterior, np.zeros(2), moved, GAIN, OFFSET, DT)


def test_a_reading_within_what_a_held_light_predicts_holds_and_one_beyond_it_drifts():
    modes = LightModes(3.0, HOLDING, MOVING, start=0.01)
    assert modes.advance(DT) is False
    _frame(modes, 0.5)
    assert modes.probability < 0.01 + 0.06  # (no more than the chain's switching lets in)
    assert modes.advance(DT) is False
    _frame(modes, 8.0)
    assert modes.probability > 0.5
    assert modes.advance(DT) is True and modes.rates() == MOVING and modes.drifted == 1


def test_a_drift_is_remembered_for_a_few_frames_then_let_go():
    """A light that drifted a frame ago is likelier drifting still: quiet frames after it are predicted in the
    drifting mode while the chain's memory and their readings allow, then hold again."""
    modes = LightModes(3.0, HOLDING, MOVING, start=0.01)
    modes.advance(DT)
    _frame(modes, 8.0)
    kept = 0
    while modes.advance(DT):
        _frame(modes, 0.0)
        kept += 1
        assert kept < 100
    assert kept >= 1 and modes.rates() == HOLDING
    modes.reset()
    assert modes.probability == 0.01 and not modes.drifting  # (as it started)


@pytest.mark.parametrize("case", ["no switching", "no interval", "nothing read"])
def test_no_reading_or_no_second_mode_decides_nothing(case):
    modes = LightModes(0.0 if case == "no switching" else 3.0, HOLDING, MOVING, start=0.01)
    modes.advance(DT)
    before = modes.probability
    prior = np.diag([1e-8, 1e-4])
    posterior = prior if case == "nothing read" else prior / 2.0
    modes.weigh(prior, posterior, np.zeros(2), np.array([1.0, 0.0]), GAIN, OFFSET, 0.0 if case == "no interval" else DT)
    if case == "nothing read":  # the chain's own prediction over the interval, no frame's word on it
        switch = -math.expm1(-3.0 * DT)
        assert modes.probability == pytest.approx(0.01 * (1.0 - switch) + 0.99 * switch)
    else:
        assert modes.probability == before
    if case == "no switching":  # one mode, the drifting one, throughout
        assert modes.drifting and modes.rates() == MOVING
