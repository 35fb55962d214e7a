"""The sensor's map kept between runs and told as it changes (core/estimator/sensor_map.py: ``state``, ``restore``,
``marks``, ``look``), and the live estimator taking a saved one (core/estimator/live.py). A map of two rows of 50
pixels with samples set as the estimator's filters leave them once the motion has resolved a speck; the live
estimator's on the seed paper's rig."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from graytrack.core.estimator.live import LOOK_FRAMES, LiveEstimator
from graytrack.core.estimator.sensor_map import CHANGED_Z, SensorMap
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model

pytestmark = pytest.mark.unit
ROW, ROWS = 50, 2
MEAN_GRAY = 100.0


def blank() -> SensorMap:
    """A map as the estimator makes one (read variance 4 gray², shot gain 0.1, dark 5; a 5σ test)."""
    return SensorMap(ROW * ROWS, np.array([4.0, 0.1, 5.0]), 1.0, 5.0, np.array([0.04, 25.0, 1e-6, 1e-3]), MEAN_GRAY,
                     0.5, 2, ROW)


def speck(sensor: SensorMap, samples: range, gain: float, offset: float = 0.2, sigma_gain: float = 0.01,
          sigma_offset: float = 0.5) -> None:
    """``samples`` resolved by the motion: the pair known to ``sigma_gain`` and ``sigma_offset`` (gray)."""
    where = np.asarray(samples)
    sensor.touched[where] = True
    sensor.f[where], sensor.e[where] = gain - 1.0, offset
    sensor.sff[where], sensor.see[where], sensor.sfe[where] = sigma_gain ** 2, sigma_offset ** 2, 0.0
    sensor.evidence[where] = sensor.rivalry[where] = 40.0
    sensor.travel[where] = 2.0  # held its own while the print moved two pixels under it
    sensor.active = True


def dusty() -> SensorMap:
    sensor = blank()
    speck(sensor, range(10, 15), 0.7)  # row 0, pixels 10-14
    speck(sensor, range(45, 55), 0.8)  # across the end of row 0 into row 1: two marks
    speck(sensor, range(70, 73), 0.9, sigma_gain=0.02)  # row 1, pixels 20-22
    sensor.touched[90] = True  # touched, not resolved: at its jump's width
    sensor.sff[90], sensor.see[90] = 0.04, 25.0 * MEAN_GRAY ** 2
    return sensor


def test_marks_are_runs_of_learned_samples_along_a_row_with_their_gain_offset_and_sigma() -> None:
    marks = dusty().marks()
    assert [(m["row"], m["first_px"], m["last_px"], m["samples"]) for m in marks] == \
        [(0, 10, 14, 5), (0, 45, 49, 5), (1, 0, 4, 5), (1, 20, 22, 3)]
    assert [m["gain"] for m in marks] == [0.7, 0.8, 0.8, 0.9]
    assert [m["gain_sigma"] for m in marks] == [0.01, 0.01, 0.01, 0.02]
    assert all(m["offset_gray"] == 0.2 and m["offset_sigma_gray"] == 0.5 for m in marks)
    assert blank().marks() == []


def test_a_state_restores_the_same_map_through_json() -> None:
    sensor = dusty()
    state = json.loads(json.dumps(sensor.state()))
    assert state["samples"] == 100 and state["rows"] == 2 and state["pixels"] == 50
    assert len(state["touched"]) == 19 and sum(state["learned"]) == 18 and len(state["marks"]) == 4
    again = blank()
    again.restore(state)
    assert again.active and np.array_equal(again.touched, sensor.touched)
    held = sensor.learned()
    for name in ("f", "e", "sff", "sfe", "see", "evidence", "rivalry", "travel"):
        assert np.array_equal(getattr(again, name)[held], getattr(sensor, name)[held]), name
    assert np.array_equal(again.learned(), sensor.learned()) and again.marks() == sensor.marks()
    assert again.look(1) == []  # what was restored is what the next look compares against: not learned again
    empty = blank()
    empty.restore(blank().state())
    assert not empty.active and not empty.touched.any()


def test_a_pair_is_told_only_once_it_has_held_its_own_over_a_pixel_of_the_prints_motion() -> None:
    """A pair the frames have narrowed (a pixel the calibration leaves a little off) takes a speck the print carries
    onto its pixel within its width, where the print's side holds no candidate, and beats the print's side for a
    frame or two (seen: told as a contrast change of one pixel, then dropped). A mark on the sensor's side keeps
    beating it while the print moves on under it."""
    sensor = dusty()
    assert sensor.learned()[10:15].all()
    sensor.travel[10:15] = 0.4
    assert not sensor.learned()[10:15].any()
    state = json.loads(json.dumps(dusty().state()))
    del state["travel"]  # a document from before the travel was kept: its marks as carried far enough
    again = blank()
    again.restore(state)
    assert again.learned()[10:15].all() and again.marks() == dusty().marks()


def test_a_candidate_the_last_run_had_not_decided_comes_back_as_just_landed() -> None:
    """Its pair and evidence spoke of the print as it passed then: restored as they were, a candidate resolved by the
    last run's motion with its evidence won would be told at this run's first deviation at its sample (seen in the
    daemon: dust on the print at rest after a restart, told on the sensor's side at the 20th frame). It comes back
    as calibrated at the jumps' width with no evidence, to be decided by this run's motion; a mark stays a mark."""
    sensor = dusty()
    speck(sensor, range(30, 33), 1.0, offset=0.0)  # resolved at calibration's light, its evidence won: undecided
    assert not sensor.learned()[30:33].any()
    again = blank()
    again.restore(json.loads(json.dumps(sensor.state())))
    assert again.touched[30:33].all() and again.touched[90]
    for p in (30, 31, 32, 90):
        assert (again.f[p], again.e[p], again.sfe[p], again.evidence[p], again.rivalry[p]) == (0.0, 0.0, 0.0, 0.0, 0.0)
        assert (again.sff[p], again.see[p]) == (again.params[0], again.params[1])
    assert again.learned()[10:15].all() and again.marks() == sensor.marks()


def test_a_state_written_before_the_rivalry_was_kept_restores_it_from_the_evidence() -> None:
    """A document without ``rivalry`` (the evidence over the print's candidate) was written when the evidence over
    the calibration was the only one: it stands for both, and the same samples are learned."""
    sensor = dusty()
    state = json.loads(json.dumps(sensor.state()))
    del state["rivalry"]
    again = blank()
    again.restore(state)
    assert np.array_equal(again.rivalry, sensor.evidence)
    assert np.array_equal(again.learned(), sensor.learned())


def test_a_pair_the_prints_candidate_explains_as_well_is_not_told() -> None:
    """One sample made 30 % darker while the light under it changes (the motion resolves the pair): told as a mark
    when the print's side holds nothing there (its account is the calibration's), not when the print's candidate
    at that sample predicts the same darkening — then the frames say something changed (its evidence over the
    calibration grows) but not on which side (its rivalry stays near nought), and the map does not say it."""
    rng = np.random.default_rng(3)
    told = {}
    for candidate in (False, True):
        sensor = blank()
        sensor.active = True
        mask, noise_var = np.ones(sensor.touched.size), np.full(sensor.touched.size, 4.0 + 0.1 * 95.0)
        sensor.land(np.where(np.arange(sensor.touched.size) == 7, 100.0, 0.0), mask / noise_var)
        for frame in range(200):
            h = np.full(sensor.touched.size, 60.0 + 80.0 * (frame % 20) / 19.0)
            y = h * np.where(np.arange(h.size) == 7, 0.7, 1.0) + rng.normal(0.0, 3.0, h.size)
            rival = h * np.where(np.arange(h.size) == 7, 0.7, 1.0) if candidate else h
            rival_var = np.where(np.arange(h.size) == 7, (0.01 * h) ** 2, 0.0) if candidate else np.zeros(h.size)
            sensor.learn(y, h, rival, rival_var, noise_var, mask, 0.05, moved=0.5)  # the print half a pixel on
        assert sensor.touched[7] and sensor.evidence[7] > 100.0
        told[candidate] = bool(sensor.learned()[7])
        if candidate:
            assert abs(sensor.rivalry[7]) < 0.5 * sensor.z2, sensor.rivalry[7]
    assert told == {False: True, True: False}


@pytest.mark.parametrize("change,reason", [
    (lambda s: s.update(samples=101), "101 samples of 50 pixels, the map has 100 of 50"),
    (lambda s: s.update(pixels=100), "the map has 100 of 50"),
    (lambda s: s.update(version=7), "version 7, not 1"),
    (lambda s: s["f"].pop(), "lengths"),
    (lambda s: s["touched"].__setitem__(0, 100), "within 0..99"),
    (lambda s: s["touched"].__setitem__(1, s["touched"][0]), "distinct"),
    (lambda s: s["e"].__setitem__(0, math.nan), "not finite"),
    (lambda s: s["sfe"].__setitem__(0, 1.0), "not positive semidefinite"),
    (lambda s: s.pop("see"), "not a sensor map state (KeyError"),
])
def test_a_state_that_does_not_fit_is_refused_in_one_line_and_changes_nothing(change, reason) -> None:
    state = json.loads(json.dumps(dusty().state()))
    change(state)
    sensor = blank()
    speck(sensor, range(30, 33), 0.5)
    before = sensor.state()
    with pytest.raises(ValueError, match=reason.replace("(", r"\(").replace(".", r"\.")) as refused:
        sensor.restore(state)
    assert "\n" not in str(refused.value)
    assert sensor.state() == before
    with pytest.raises(ValueError, match="not a sensor map state"):
        sensor.restore([1, 2])  # type: ignore[arg-type]


def test_a_look_tells_marks_learned_changed_and_dropped_once() -> None:
    sensor = dusty()
    first = sensor.look(20)
    assert [(e.what, e.frame, e.mark["first_px"]) for e in first] == \
        [("learned", 20, 10), ("learned", 20, 45), ("learned", 20, 0), ("learned", 20, 20)]
    assert sensor.look(40) == []
    speck(sensor, range(15, 16), 0.7)  # the mark grew by a sample, its figures the same: refined, not told
    sensor.f[10:15] += 0.5 * CHANGED_Z * 0.01 * math.sqrt(2)  # moved by half of what tells a change
    assert sensor.look(60) == []
    sensor.f[10:16] -= 0.2  # more dust on it: 20 % of the light, far beyond its σ
    changed = sensor.look(80)
    assert [(e.what, e.mark["first_px"], e.mark["last_px"]) for e in changed] == [("changed", 10, 15)]
    assert changed[0].mark["gain"] == pytest.approx(0.5 + 0.5 * CHANGED_Z * 0.01 * math.sqrt(2) * 5 / 6, abs=1e-3)
    sensor.sff[70:73] = 0.04  # a jump widened the mark of row 1: held by the map, not resolved, not told
    assert sensor.marks()[-1]["first_px"] == 0 and sensor.look(100) == []
    sensor.sff[70:73] = 0.02 ** 2  # resolved again, as it was: nothing to tell
    assert sensor.look(120) == [] and len(sensor.marks()) == 4
    sensor.reset()  # the frames read as calibrated again everywhere: the map let every sample go
    dropped = sensor.look(140)
    assert sorted(e.what for e in dropped) == ["dropped"] * 4
    assert len(sensor.events) == 4 + 1 + 4 and sensor.look(160) == []


@pytest.fixture(scope="module")
def paper():
    return rig_model("paper", "", seed=4, seconds=20.0)


def test_the_live_estimator_takes_a_saved_map_or_says_why_not_and_tracks_without_it(paper) -> None:
    run, _ = build_rig("paper", "", seed=4, run=1).record(2.0)
    said: list[tuple[str, str]] = []

    def refuse(name: str, reason: str) -> None:
        said.append((name, reason))

    refused = LiveEstimator(paper, float(run.reference[0]), sensor_map=dusty().state(), refused=refuse)
    assert said == [("sensor_map", f"100 samples of 50 pixels, the map has {paper.n_pixels * paper.n_rows} of "
                                   f"{paper.n_pixels}")]
    assert not refused.sensor_map.active
    fitting = SensorMap(paper.n_pixels, np.array([4.0, 0.1, 5.0]), 1.0, 5.0, np.ones(4), MEAN_GRAY, 0.5, 2,
                        paper.n_pixels)
    speck(fitting, range(40, 46), 0.7)
    taken = LiveEstimator(paper, float(run.reference[0]), sensor_map=fitting.state(), refused=refuse)
    assert len(said) == 1 and taken.sensor_map.active and taken.sensor_map.marks() == fitting.marks()
    for k in range(LOOK_FRAMES):
        fix = refused.update(run.frames[k], float(run.reference[k]), float(run.t[k]))
        assert math.isfinite(fix.x_mm)
    # a clean run: nothing lands, nothing is told (the map is looked at every LOOK_FRAMES frames)
    assert refused.frames == LOOK_FRAMES and refused.sensor_map.events == [] and not refused.sensor_map.active
