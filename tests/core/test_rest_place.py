"""A stage resting after the daemon's quick calibration (21 stops of 3 frames, the paper model): the
model's own stretch and focus at the place it rests (core/place_spread.py) are no magnification and
no blur; a lens that really changes while it rests still is named. Tracked as the daemon tracks (its
scale watch carries the magnification watch: service/daemon/trim.py), from the same rig's later run
(fresh noise)."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.recording import Recording
from graytrack.core.place_spread import model_share
from graytrack.core.tracking import LiveTracker
from graytrack.core.validity import FrameSign
from graytrack.core.watches.focus import FocusWatch
from graytrack.core.watches.scale import ScaleWatch
from graytrack.drivers.sim.scenarios import build_rig

FRAME_RATE_HZ = 20.0
REST_MM = (1.0, 5.0)  # places where the model's own stretch reads ±800-1300 ppm, 4-5 σ of a 50-frame mean's noise


def at_rest(rig, x_mm: float, n: int) -> np.ndarray:
    return rig.render(np.full(n, x_mm), np.arange(n) / FRAME_RATE_HZ)


@pytest.fixture(scope="module")
def model():
    rig = build_rig("paper", seed=0)
    x = np.repeat(np.linspace(0.1, 10.36, 21), 3)
    t = np.arange(x.size) / FRAME_RATE_HZ
    step = rig.config.grating.resolution_mm
    recording = Recording(rig.render(x, t)[:, 0, :], t,
                          np.round(x / step) * step, rig.meta())
    return calibrate(recording, "paper").model


def reasons(model, rig, x_mm: float, n: int) -> collections.Counter:
    tracker = LiveTracker(model, x_mm, watches=[ScaleWatch.for_model(model)])
    frames = at_rest(rig, x_mm, n)
    return collections.Counter(fix.stale_reason for fix in (tracker.update(frame, x_mm) for frame in frames))


@pytest.mark.parametrize("x_mm", REST_MM)
def test_a_steady_stage_at_rest_is_not_flagged(model, x_mm):
    seen = reasons(model, build_rig("paper", seed=0, run=1), x_mm, 200)
    assert seen[None] == 200, seen  # before: magnification on 165 and 54 of these 200 frames


def test_a_lens_changing_while_the_stage_rests_is_still_named(model):
    rig = build_rig("paper", "magnification_drift:ppm=8000:ramp_s=4:axis_px=0", seed=0, run=1)
    seen = reasons(model, rig, 5.0, 200)
    assert seen["magnification"] > 60, seen


def focus_flags(watch: FocusWatch, places_mm: np.ndarray, change_px2: float, seed: int = 1) -> int:
    """Frames flagged ``focus`` of a run whose focus estimates (σ 3.2 px², as a one-row paper frame's)
    read ``change_px2`` at ``places_mm``."""
    rng = np.random.default_rng(seed)
    signs = (FrameSign(k, chi2=1.0, focus=change_px2 + 3.2 * rng.standard_normal(), focus_sigma=3.2, x_mm=float(x))
             for k, x in enumerate(places_mm))
    return sum(watch.observe(sign) == "focus" for sign in signs)


def test_the_models_own_focus_at_the_resting_place_is_no_blur_and_a_change_over_many_places_is(model):
    """6 px² in every estimate: at one place it may be the model's own there (seed 2's read 2.5 ±
    0.6 px² at 3.33 mm, flagged on 70 of a rest's frames); over the stroke it is a blur."""
    share = model_share(model)
    assert 0.15 < share < 0.25  # 0.3 × 44 coefficients / 63 frames
    assert focus_flags(FocusWatch(place_share=share), np.full(300, 3.33), 6.0) == 0
    assert focus_flags(FocusWatch(), np.full(300, 3.33), 6.0) > 240  # the window's noise alone: flagged
    moving = np.linspace(0.1, 10.36, 300)
    assert focus_flags(FocusWatch(place_share=share), moving, 6.0) > 240  # of the 251 judged
