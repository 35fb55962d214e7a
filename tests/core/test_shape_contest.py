"""The light's shape at the first frames, as calibrated or changed since (core/estimator/shape_contest.py).

Nobody tells the estimator that the light changed between calibration and the run: a lamp's vignetting deeper, light
uneven along the print. From the image alone a shape held as calibrated took such a change as a shift, 30-60 µm off
under a 1-5 µm bound with no flag (the paper rig's vignetting: 79 frames of 500 silently off); where nothing changed,
the shape held as calibrated is the better (a clean 16-row strip)."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.estimator import filter as estimator
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.estimator.shape_contest import ShapeContest
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import estimator_figures, rig_model

pytestmark = pytest.mark.unit


def test_the_contest_takes_the_rival_only_on_evidence_at_the_false_alarm_rate():
    held = ShapeContest(rival=None, threshold=6.9, frames=30)
    assert [held.weigh(0.0, -0.1, True) for _ in range(29)] == [""] * 29 and held.weigh(0.0, -0.1, True) == "held"
    taken = ShapeContest(rival=None, threshold=6.9, frames=30)
    assert taken.weigh(-100.0, -96.0, True) == "" and taken.weigh(-100.0, -96.0, True) == "rival"  # 8 nats, 2 frames
    refuted = ShapeContest(rival=None, threshold=6.9, frames=30)
    assert refuted.weigh(0.0, -7.0, True) == "held"
    unexplained = ShapeContest(rival=None, threshold=6.9, frames=3)  # a frame it did not explain: a misfit, no shape
    assert [unexplained.weigh(-900.0, -500.0, ok) for ok in (False, True, True)] == ["", "", "held"]


@pytest.fixture(scope="module")
def paper():
    return rig_model("paper")


@pytest.mark.parametrize("later", ["vignetting:edge=0.15", "gradient:per_10mm=0.05"])
def test_a_light_changed_before_the_run_is_not_taken_as_a_shift(paper, later):
    run, truth = build_rig("paper", later, seed=3, run=1).record(10.0)
    figures = estimator_figures(paper, run, truth, "none")
    # (held as calibrated: the vignetting 54.8 µm, 79 frames silent; the gradient 10.4 µm, 18 silent)
    assert figures["silent"] <= 0.005 * truth.x_mm.size, figures
    assert figures["std"] < 3.0, figures  # µm (the clean run's 1.5)


def test_where_nothing_changed_the_shape_as_calibrated_stands():
    model = rig_model("strip16")
    run, truth = build_rig("strip16", "", seed=3, run=1).record(10.0)
    for grating in ("check", "none"):
        contested = estimator.track(model, run.frames, run.t, run.reference, grating=grating)
        held = estimator.track(model, run.frames, run.t, run.reference, grating=grating,
                               settings=EstimatorSettings().replace(shape_contest_frames=0))
        assert np.array_equal([e.x_mm for e in contested], [e.x_mm for e in held]), grating
