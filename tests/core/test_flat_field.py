"""The sensor's rough pattern calibration's sweep measures for the estimator (core/estimator/flat_field.py): taken
out where it is the sensor's and pays, kept out where it is the print's, a flickering pixel's or noise."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.estimator import EstimatorSettings
from graytrack.core.estimator.filter import CALIBRATION_ERROR, Estimator, track
from graytrack.core.estimator.flat_field import FLAT_FIELD, STRETCHES, FlatField, pattern
from graytrack.core.recording import acceleration_phases
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model

FIXED_PATTERN = "prnu:sigma=0.03,dsnu:sigma=2"  # each pixel's own gain and dark level, as calibrated
GLARE = "glare:gray=20"  # a bright blob a few pixels wide fixed to the camera


def _sums(h: np.ndarray, r_of, rng: np.random.Generator, noise: float = 1.0) -> np.ndarray:
    """The stretches' sums of frames whose model values ``h`` (frames × samples) read ``r_of(stretch, h)`` beyond
    them, with white noise of ``noise`` (unit weights)."""
    sums = np.zeros((STRETCHES, 5, h.shape[1]))
    for k, values in enumerate(h):
        stretch = k * STRETCHES // h.shape[0]
        r = r_of(stretch, values) + noise * rng.standard_normal(values.size)
        sums[stretch] += [values * values, values, np.ones_like(values), values * r, r]
    return sums


@pytest.fixture(scope="module")
def sweep():
    rng = np.random.default_rng(5)
    samples = 64
    phase = np.linspace(0.0, 40.0 * np.pi, 800)[:, None] + np.linspace(0.0, 6.0, samples)[None, :]
    h = 100.0 + 40.0 * np.sin(phase)
    u = np.linspace(-1.0, 1.0, samples)
    basis = np.stack([np.ones(samples), u, 1.5 * u * u - 0.5], axis=1)
    return rng, h, basis, u


def test_a_pattern_fixed_to_the_pixels_is_found_and_its_smooth_part_left_to_the_model(sweep):
    rng, h, basis, u = sweep
    rough_f = 0.03 * rng.standard_normal(h.shape[1])
    rough_e = 2.0 * rng.standard_normal(h.shape[1])
    smooth = 0.05 * u  # a gain sloping across the pixels: the model's polynomials' (and the light field's)
    f, e = pattern(_sums(h, lambda _, v: (rough_f + smooth) * v + rough_e, rng), basis, 9.0)
    # what is found is the rough part (less its own projection on the polynomials), sample by sample
    expected_f = rough_f - basis @ np.linalg.lstsq(basis, rough_f, rcond=None)[0]
    expected_e = rough_e - basis @ np.linalg.lstsq(basis, rough_e, rcond=None)[0]
    assert np.count_nonzero(f) > 0.9 * f.size
    assert np.sqrt(np.mean((f - expected_f) ** 2)) < 0.1 * np.std(expected_f)
    assert np.sqrt(np.mean((e - expected_e) ** 2)) < 0.1 * np.std(expected_e)


def test_what_one_stretch_of_the_stroke_shows_and_the_next_does_not_is_not_the_sensors(sweep):
    """Marks the print carries past the samples read at each on some stretches of the stroke, each stretch its own
    (another mark, or the same at another pixel): the pattern each half of the stretches finds does not predict the
    other half's, and the samples keep none; noise alone keeps next to none."""
    rng, h, basis, _ = sweep
    print_side = 3.0 * rng.standard_normal((STRETCHES, h.shape[1])) * (rng.random((STRETCHES, 1)) < 0.5)
    f, e = pattern(_sums(h, lambda stretch, v: print_side[stretch] + 0.0 * v, rng), basis, 9.0)
    assert np.count_nonzero(e) < 0.1 * e.size
    f, e = pattern(_sums(h, lambda _, v: 0.0 * v, rng), basis, 9.0)
    assert np.count_nonzero(f) + np.count_nonzero(e) <= 2


def test_a_document_of_another_shape_or_version_is_not_read():
    good = FlatField(np.ones(4) * 1.01, np.zeros(4), 1.2, None, 1.0, 4).as_dict()
    assert FlatField.from_info({FLAT_FIELD: good}, 4) is not None
    assert FlatField.from_info({FLAT_FIELD: good}, 5) is None
    assert FlatField.from_info({FLAT_FIELD: {**good, "version": 99}}, 4) is None
    assert FlatField.from_info({FLAT_FIELD: {**good, "gain": [1.0, -1.0, 1.0, 1.0]}}, 4) is None
    assert FlatField.from_info({FLAT_FIELD: {**good, "level": float("nan")}}, 4) is None
    assert FlatField.from_info({}, 4) is None


def _error_um(model, run, truth, grating: str = "check") -> tuple[float, float]:
    """The estimator's error std against the rig's truth (µm) and its rms pull over the stated bound."""
    estimator = Estimator(model, settings=EstimatorSettings().for_recording(run.meta), grating=grating,
                          stage_phases=acceleration_phases(run.meta))
    estimates = track(model, run.frames, run.t, run.reference, estimator=estimator)
    error = (np.array([e.x_mm for e in estimates]) - truth.x_mm) * 1e3
    bound = np.array([e.crlb_mm for e in estimates]) * 1e3
    placed = np.isfinite(error)
    assert placed.mean() > 0.99
    return float(np.std(error[placed])), float(np.sqrt(np.mean((error[placed] / bound[placed]) ** 2)))


def _without(model):
    return model.with_changes(info={key: value for key, value in model.info.items() if key != FLAT_FIELD})


@pytest.mark.parametrize("effects, gain", [(FIXED_PATTERN, 0.45), (GLARE, 0.7)])
def test_a_pattern_on_the_sensor_is_taken_out_and_the_bound_stays_honest(effects, gain):
    """Each pixel's own gain and dark level (3 %, 2 gray) and a glare's blob fixed to the camera: the model's smooth
    coefficients cannot hold them, and the estimator's light and focus chased them as the print moved under them.
    Taken out, a steady run errs less than half (a third under the pattern: 7.3 → 2.5 µm; the glare 9.4 → 5.5 µm),
    in either mode, with its bound what it errs by."""
    model = rig_model("paper", effects, seed=3)
    # (without what repeats at each place of the stroke taken out: tests/core/test_error_map.py reads that)
    model = model.with_changes(info={**model.info, CALIBRATION_ERROR: {
        key: value for key, value in model.info[CALIBRATION_ERROR].items() if key != "map"}})
    field = model.info.get(FLAT_FIELD)
    assert field and field["kept"] > 80 and field["level"] < 0.2 * model.info["calibration_chi2"]
    run, truth = build_rig("paper", effects, seed=3, run=1).record(10.0)
    for grating in ("check", "none"):
        with_it, pull = _error_um(model, run, truth, grating)
        without_it, _ = _error_um(_without(model), run, truth, grating)
        assert with_it < gain * without_it
        if grating == "check":
            assert 0.8 <= pull <= 1.25


@pytest.mark.parametrize("effects", ["telegraph_pixels:count=3", "glints:p=0.05", ""])
def test_what_is_not_a_fixed_pattern_is_not_taken_out(effects):
    """Pixels flipping between two levels, glints on a frame in twenty and a clean rig: a pattern fitted there is a
    mean no frame reads (it set the telegraph pixels half a swing off on every frame: 1.11 → 1.58 noise floors) or
    noise, and none is kept (calibration sets the telegraph pixels aside: tests/core/test_two_level.py)."""
    model = rig_model("paper", effects, seed=3)
    assert model.info.get(FLAT_FIELD) is None
