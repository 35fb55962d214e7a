"""The rig at the first frames, as calibrated or changed since (core/estimator/shape_contest.py).

Nobody tells the estimator that the rig changed between calibration and the run: a lamp's vignetting deeper, light
uneven along the print, a lens refocused. From the image alone a rig held as calibrated took such a change as a shift,
30-60 µm off under a 1-5 µm bound with no flag (the paper rig's vignetting: 79 frames of 500 silently off); where
nothing changed, the rig held as calibrated is the better (a clean 16-row strip), and the contest changes nothing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core.estimator import filter as estimator
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.estimator.shape_contest import Rival, ShapeContest
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import estimator_figures, rig_model

pytestmark = pytest.mark.unit


def test_a_rival_takes_over_only_on_evidence_at_the_false_alarm_rate_having_explained_every_frame():
    def contest(frames=30):
        return ShapeContest([Rival("shape", 6.9), Rival("stretch", 5.4)], frames)

    held = contest()
    assert [held.weigh(0.0, [-0.1, -0.1], [True, True]) for _ in range(29)] == [None] * 29
    assert held.weigh(0.0, [-0.1, -0.1], [True, True]) is True  # nothing said the rig changed
    taken = contest()
    assert taken.weigh(-100.0, [-96.0, -99.0], [True, True]) is None  # 4 nats for the shape: not yet
    assert taken.weigh(-100.0, [-96.0, -99.0], [True, True]).estimator == "shape"  # 8 over two frames
    refuted = contest()
    assert refuted.weigh(0.0, [-7.0, -1.0], [True, True]) is None and [r.estimator for r in refuted.rivals] == \
        ["stretch"]  # the shape's rival out, the stretch's still weighed
    assert refuted.weigh(0.0, [math.nan], [True]) is None  # (a frame it could not weigh says nothing)
    assert refuted.weigh(0.0, [-5.0], [True]) is True  # the stretch's rival out too: the rig as calibrated
    unexplained = contest(3)  # a frame it did not explain: a misfit, not a change
    assert [unexplained.weigh(-900.0, [-500.0, -950.0], [ok, True]) for ok in (False, True)] == [None, None]
    assert unexplained.weigh(-900.0, [-500.0, -950.0], [True, True]) is True


@pytest.fixture(scope="module")
def paper():
    return rig_model("paper")


@pytest.mark.parametrize("later", ["vignetting", "gradient", "magnification"])
def test_a_light_changed_before_the_run_is_not_taken_as_a_shift(paper, later):
    run, truth = build_rig("paper", later, seed=3, run=1).record(10.0)
    # (the stretch's rival is one a user who refocuses the lens between calibration and the run declares)
    settings = EstimatorSettings().replace(stretch_changed_prior=0.1) if later.startswith("magnification") else None
    figures = estimator_figures(paper, run, truth, "none", settings)
    said = [e.message for e in estimator.track(paper, run.frames, run.t, grating="none", settings=settings)
            if "changed since calibration" in e.message]
    assert len(said) == 1 and said[0].startswith("the magnification" if settings else "the light's shape"), said
    # (held as calibrated, shape_contest_frames=0: the vignetting 33.1 µm, 79 frames silent; the gradient 10.4 µm,
    # 18 silent; the lens refocused 10 % 60.4 µm, 22 silent)
    assert figures["silent"] <= 0.005 * truth.x_mm.size, figures
    if not later.startswith("magnification"):  # (a lens refocused slides the image by what no frame sees: a bound)
        assert figures["std"] < 3.0, figures  # µm (the clean run's 1.5)


def test_where_nothing_changed_the_shape_as_calibrated_stands():
    model = rig_model("strip16")
    run, truth = build_rig("strip16", "", seed=3, run=1).record(10.0)
    for grating in ("check", "none"):
        contested = estimator.track(model, run.frames, run.t, run.reference, grating=grating)
        held = estimator.track(model, run.frames, run.t, run.reference, grating=grating,
                               settings=EstimatorSettings().replace(shape_contest_frames=0))
        assert np.array_equal([e.x_mm for e in contested], [e.x_mm for e in held]), grating
