"""What a calibration keeps place by place, read for a frame placed only up to whole periods (a model
that repeats once a period, tracked without a grating: core/stroke_place.py), and what a lossy
stream does to a frame's χ² spread. The 16-row MJPEG strip's closed-loop model, tracked with
``--no-reference``, started a period (8.62 mm) from the stage: its χ² level and its own stretch,
both varying along the stroke with the stream's quantisation, were read a period away, and a steady
run was flagged on 21 % of its frames (`geometry`, then `magnification`) with a blur suspected on 309."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from graytrack.core.adequacy import chi2_spread
from graytrack.core.chi2_curve import Chi2Curve
from graytrack.core.slide import SlideWatch
from graytrack.core.watches.magnification import StretchProfile

PERIOD_MM = 8.620224567547952
# the 16-row MJPEG strip's closed-loop model (quality 75, seed 3): its χ² level and own stretch along the stroke
CURVE_X = tuple(0.16 + 0.3245 * i for i in range(32))
CURVE_LEVEL = (0.91, 0.91, 0.92, 0.89, 0.94, 0.96, 1.06, 1.08, 1.16, 1.11, 1.11, 1.08, 1.04, 1.08, 1.11, 1.04, 1.05,
               1.02, 1.01, 1.05, 1.04, 1.02, 1.0, 1.02, 0.97, 1.03, 0.92, 0.91, 0.85, 0.89, 0.92, 0.89)
PROFILE = {"centers_mm": [0.4, 1.0, 1.6, 2.3, 2.9, 3.5, 4.4, 4.9, 5.5, 6.2, 6.8, 7.5, 8.2, 8.8, 9.5, 10.1],
           "values_ppm": [-143.4, 99.7, -12.7, 118.4, -149.3, -115.3, 146.7, -5.5, -175.8, 68.0, -508.7, -7.5, 280.9,
                          -225.6, 256.7, 80.4], "residual_ppm": 42.78}


def test_an_unplaced_frame_is_held_against_the_highest_chi2_level_it_may_be_at():
    curve = Chi2Curve(CURVE_X, CURVE_LEVEL)
    for x in np.linspace(0.2, 1.6, 8):  # both x and x + a period on the stroke: the higher of the two
        expected = max(curve.at(x), curve.at(x + PERIOD_MM))
        assert math.isclose(curve.anywhere(x + PERIOD_MM, PERIOD_MM), expected)
        assert math.isclose(curve.anywhere(x, PERIOD_MM), expected)
    # the run's frames (the stage at 0-5 mm, placed a period on): read where placed they were 7-25 % low
    truth = np.linspace(0.2, 5.0, 50)
    placed = [curve.at(x + PERIOD_MM) / curve.at(x) for x in truth]
    anywhere = [curve.anywhere(x + PERIOD_MM, PERIOD_MM) / curve.at(x) for x in truth]
    assert min(placed) < 0.8 and min(anywhere) >= 1.0 - 1e-12
    assert curve.anywhere(3.0, 0.0) == curve.at(3.0)


def _slide_flags(profile: dict, truth_mm: np.ndarray, offset_mm: float, lens_ppm: float, seed: int = 0) -> int:
    """Frames the no-grating magnification watch flags: each frame's stretch is the model's own at the
    stage's true place plus a lens's ``lens_ppm``, each known to 200 ppm, while the frame is placed
    ``offset_mm`` from the truth."""
    model = SimpleNamespace(info={"stretch_profile": profile}, period_mm=PERIOD_MM, stroke_degree=0, target_map=None,
                            pixel_pitch_mm=0.062)
    watch = SlideWatch.for_model(model)
    own = StretchProfile.from_dict(profile)
    rng = np.random.default_rng(seed)
    flagged = 0
    for frame, x in enumerate(truth_mm):
        m = (own.at_ppm(x) + lens_ppm + 200.0 * rng.standard_normal()) * 1e-6
        flagged += watch.step(frame, True, x + offset_mm, lambda m=m: (m, 200e-6), math.nan) is not None
    return flagged


def test_a_models_own_stretch_read_a_period_away_is_no_magnification_and_a_lens_still_is():
    truth = np.linspace(0.2, 5.0, 500)
    assert _slide_flags(PROFILE, truth, 0.0, 0.0) == 0
    assert _slide_flags(PROFILE, truth, PERIOD_MM, 0.0) == 0  # 85 of 500 flagged before the profile folded
    assert _slide_flags(PROFILE, truth, PERIOD_MM, 1500.0) > 400  # a lens 0.15 % off: still found
    folded = StretchProfile.from_dict(PROFILE).folded(PERIOD_MM)
    assert folded.residual_ppm > 100.0  # the places' spread: what the watch allows the model's own stretch
    assert folded.residual_ppm > StretchProfile.from_dict(PROFILE).residual_ppm
    assert math.isclose(folded.at_ppm(2.0), folded.at_ppm(2.0 + PERIOD_MM))


def test_a_streams_chi2_spread_is_measured_against_white_noise_in_as_many_samples():
    rng = np.random.default_rng(1)
    used = np.full(400, 2048)
    white = rng.chisquare(2048, 400) / 2048
    assert abs(chi2_spread(white, used) - 1.0) < 0.15
    coarse = rng.chisquare(200, 400) / 200  # an error in ~200 coarse coefficients, spread over 2,048 samples
    assert abs(chi2_spread(coarse, used) - math.sqrt(2048 / 200)) < 0.5
    assert chi2_spread(np.ones(1), np.ones(1)) == 1.0
