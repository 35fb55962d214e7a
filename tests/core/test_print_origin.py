"""What a run starts from on the print: the marks calibration's own sweep learned (filter.py
``calibration_print_map``, surveyed at ``CALIBRATION_SURVEY_SIGMA``), read at the run's coordinates; without the
grating, after the marks themselves told which whole period of the print the run is at (print_origin.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.estimator import EstimatorSettings
from graytrack.core.estimator.filter import CALIBRATION_PRINT_MAP, Estimator, track
from graytrack.core.recording import acceleration_phases
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model

SCRATCHED = "scratches:count=3"  # marks on the paper print at calibration


def _learned_by_run(model, run, grating: str, start_mm: float | None = None) -> tuple[int, Estimator]:
    estimator = Estimator(model, settings=EstimatorSettings().for_recording(run.meta), grating=grating,
                          stage_phases=acceleration_phases(run.meta))
    if start_mm is not None:  # (placed from here instead of the acquisition's pick)
        estimator.start(start_mm, float(run.t[0]), 0.01)
    track(model, run.frames, run.t, run.reference, estimator=estimator)
    print_map = estimator.print_map
    return int((print_map.learned() & ~print_map.restored).sum()), estimator


@pytest.fixture(scope="module")
def scratched():
    return rig_model("paper", SCRATCHED, seed=3)


@pytest.mark.parametrize("periods", [0, 1])
def test_without_the_grating_calibrations_marks_tell_the_period_and_are_read_there(scratched, periods):
    """A run placed a whole period off the print's coordinates (as an acquisition from the image alone may pick)
    finds the period from the scratches its calibration learned, restores them there and learns none again; before,
    such a run learned 17 nodes of the scratches anew."""
    assert scratched.info.get(CALIBRATION_PRINT_MAP)
    run, truth = build_rig("paper", SCRATCHED, seed=3, run=1).record(10.0)
    start = float(truth.x_mm[0]) + periods * scratched.period_mm
    learned, estimator = _learned_by_run(scratched, run, "none", start)
    assert estimator._origin_periods == -periods
    assert learned == 0 and estimator.print_map.restored.sum() > 10
    assert estimator.print_map.shift == pytest.approx(-periods * scratched.period_mm)
    # what is kept of the run's map names the marks where they are on the print, its shift with it
    state = estimator.print_map.state()
    assert state["shift_mm"] == pytest.approx(-periods * scratched.period_mm)
    calibrated = scratched.info[CALIBRATION_PRINT_MAP]
    kept, known = (np.sort([mark["x_mm"] for mark in marks]) for marks in (state["marks"], calibrated["marks"]))
    assert kept.size == known.size and np.allclose(kept, known, atol=0.01)  # (each mark's centre as the run saw it)


def test_marks_that_are_not_the_prints_decide_no_period():
    """Calibration's map of a print without marks holds none: nothing to weigh, no period decided, the run as
    before. And marks no frame sees where they were kept (another print under the camera, or a sensor's flickering
    pixel calibration took for one) are never read: their evidence at every place falls below none."""
    plain = rig_model("paper", "", seed=3)
    run, _ = build_rig("paper", "", seed=3, run=1).record(6.0)
    _, estimator = _learned_by_run(plain, run, "none")
    assert estimator.print_origin is None and estimator._origin_periods is None
    # three marks 30 % dark, a pixel wide, where this print has none
    stray = estimator.print_map
    for place in (2.0, 5.0, 8.0):
        first = int(round((place - stray.base_origin) / stray.step))
        nodes = np.arange(first, first + 4)
        stray.touched[nodes], stray.f[nodes], stray.s[nodes] = True, -0.3, 1e-6
        stray.evidence[nodes], stray.lo[nodes], stray.hi[nodes] = 100.0, 0.0, 10.0
    assert stray.learned().sum() == 12
    foreign = dataclasses.replace(plain, info=dict(plain.info, **{CALIBRATION_PRINT_MAP: stray.state()}))
    _, estimator = _learned_by_run(foreign, run, "none")
    assert estimator.print_origin is not None and estimator._origin_periods is None
    assert estimator.print_origin.evidence and max(estimator.print_origin.evidence.values()) < 0.0
    assert not estimator.print_map.restored.any()


def test_calibration_surveys_the_prints_weak_specks_so_that_a_steady_run_learns_none():
    """The lab strip's print holds specks a few % deep: a frame's own test lands a sample on one only by chance,
    so calibration's sweep learned some and each steady run learned others (5-17 nodes with the grating read).
    Surveyed (every sample beyond 3 σ a candidate on calibration's own sweep, decided by the motion), calibration
    holds them and the run learns none."""
    calibration, _ = build_rig("lab", "", seed=3).record(6.0)
    model = calibrate(calibration, "paper").model
    run, _ = build_rig("lab", "", seed=3, run=1).record(3.0)
    bare = dataclasses.replace(model, info={k: v for k, v in model.info.items() if k != CALIBRATION_PRINT_MAP})
    unsurveyed = Estimator(bare, settings=EstimatorSettings().for_recording(calibration.meta), grating="fuse",
                           stage_phases=acceleration_phases(calibration.meta))
    track(bare, calibration.frames, calibration.t, calibration.reference, estimator=unsurveyed)
    unsurveyed.print_map.keep_learned()
    landed_only = dataclasses.replace(model, info=dict(model.info, **{CALIBRATION_PRINT_MAP:
                                                                      unsurveyed.print_map.state()}))
    surveyed = model.info[CALIBRATION_PRINT_MAP]
    assert sum(surveyed["learned"]) > 2 * sum(unsurveyed.print_map.state()["learned"])
    for grating in ("check", "none"):
        assert _learned_by_run(model, run, grating)[0] == 0
    assert _learned_by_run(landed_only, run, "check")[0] > 0
