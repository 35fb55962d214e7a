"""Model files: round trip, and refusal of other schemas and inconsistent content."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graytrack.core.errors import ModelError
from graytrack.core.models import FourierModel, load_model, model_to_dict, save_model


def test_round_trip_predicts_the_same(tmp_path, paper_models):
    model = paper_models["paper"].model
    back = load_model(save_model(model, tmp_path / "m.json"))
    x = np.linspace(0, 10, 7)
    np.testing.assert_allclose(back.predict(x), model.predict(x), rtol=1e-12)
    assert back.noise_gray == model.noise_gray and back.describe() == model.describe()


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d.update(schema="other.tool"), "not a graytrack model file"),
        (lambda d: d.update(version=99), "version 99 is not supported"),
        (lambda d: d["model"].pop("coeffs"), "lacks 'coeffs'"),
        (lambda d: d["model"]["coeffs"].update(shape=[3, 4]), "coeffs is malformed"),
        (lambda d: d["model"].update(harmonics=4), "coefficients have shape"),
        (lambda d: d["model"].update(period_mm=-1.0), "geometry must be positive"),
    ],
)
def test_bad_model_files_are_refused_by_name(tmp_path, paper_models, edit, message):
    document = model_to_dict(paper_models["paper"].model)
    edit(document)
    path = tmp_path / "m.json"
    path.write_text(json.dumps(document))
    with pytest.raises(ModelError, match=message):
        load_model(path)


def test_not_json(tmp_path):
    (tmp_path / "m.json").write_bytes(b"\x00\x01binary")
    with pytest.raises(ModelError, match="not a JSON model file"):
        load_model(tmp_path / "m.json")


def test_ideal_parameters_match_table_1(paper_models):
    params = paper_models["ideal"].model.ideal_parameters()
    assert params["A"] == pytest.approx(80, abs=6)  # paper: 79.59
    assert params["D"] == pytest.approx(125, abs=6)  # paper: 123.8
    assert params["n_coeffs"] == 3


def test_derivative_matches_finite_difference(paper_models):
    model = paper_models["paper"].model.with_changes(stroke_degree=2, coeffs=None)
    rng = np.random.default_rng(0)
    model = model.with_changes(coeffs=rng.normal(size=model.coeff_shape), stroke_range_mm=(0.0, 10.0))
    x = np.array([1.0, 4.2, 9.9])
    _, slope = model.predict(x, with_derivative=True)
    h = 1e-6
    numeric = (model.predict(x + h) - model.predict(x - h)) / (2 * h)
    np.testing.assert_allclose(slope, numeric, rtol=1e-5, atol=1e-6)


def test_constructor_checks():
    with pytest.raises(ModelError, match="harmonics"):
        FourierModel(8.6, 0.06, 100, harmonics=0)


def test_tracker_evaluator_matches_model_with_stroke_terms_and_flat_field(paper_models):
    from graytrack.core.evaluation import FastHarmonics

    base = paper_models["paper"].model
    rng = np.random.default_rng(1)
    model = base.with_changes(stroke_degree=2, n_rows=3, row_degree=1, row_shift_mm=0.01, stroke_range_mm=(0.0, 10.0))
    model = model.with_changes(coeffs=rng.normal(size=model.coeff_shape),
                               pixel_gain=1 + 0.01 * rng.normal(size=(3, 100)),
                               pixel_offset=rng.normal(size=(3, 100)))
    x = np.array([0.5, 3.7, 9.2])
    values, slopes = FastHarmonics(model).evaluate(x)
    expected_values, expected_slopes = model.predict(x, with_derivative=True)
    np.testing.assert_allclose(values, expected_values.reshape(3, -1), rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(slopes, expected_slopes.reshape(3, -1), rtol=1e-9, atol=1e-8)


@pytest.mark.parametrize("stroke_degree", [0, 2])
def test_the_weights_summed_against_are_each_frames_to_the_bit(stroke_degree):
    """Without stroke terms the model sums against the pixels' own weights, not a copy for each frame: the same
    values and slopes to the bit as with the copy (FourierModel.frame_weights)."""
    model = FourierModel(period_mm=0.86, pixel_pitch_mm=0.0054, n_pixels=60, n_rows=4, harmonics=5, pixel_degree=3,
                         stroke_degree=stroke_degree, noise_gray=1.0, name="weights")
    model = model.with_changes(coeffs=np.random.default_rng(stroke_degree).normal(0.0, 1.0, model.coeff_shape))
    x_mm = np.linspace(0.1, 10.3, 50)
    stroke, _ = model.stroke_basis(x_mm)
    weights = model.frame_weights(stroke)
    assert weights.ndim == (3 if stroke_degree == 0 else 4)
    each_frame = np.einsum("rual,kl->krua", model.spatial_weights(), stroke)
    for terms in (model.trig(x_mm), np.ascontiguousarray(model.trig(x_mm)) * 0.5):
        assert np.array_equal(model.sum_terms(terms, weights), np.einsum("krua,krua->kru", terms, each_frame))
