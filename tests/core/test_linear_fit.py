"""The normal equations' sums over the frames (core/linear_fit.py): compiled and by numpy's products they are the
same sums to rounding, on the trig terms as the model keeps them (term-major) and on their product with stroke
polynomials; and the least squares they give fit what the model predicts."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core import kernels, linear_fit
from graytrack.core.models.fourier import FourierModel

# Two summation orders of 300 products each: a few ulp of the largest sum apart, far below what any fit resolves.
SUM_TOLERANCE = 1e-13


def _model(stroke_degree: int, n_rows: int) -> FourierModel:
    return FourierModel(period_mm=0.86, pixel_pitch_mm=0.0054, n_pixels=100, n_rows=n_rows, harmonics=5,
                        pixel_degree=3, stroke_degree=stroke_degree, noise_gray=1.0, name="sums")


@pytest.mark.parametrize("stroke_degree, n_rows", [(0, 16), (2, 1), (1, 3)])
def test_the_compiled_sums_are_numpys(stroke_degree: int, n_rows: int) -> None:
    model = _model(stroke_degree, n_rows)
    x_mm = np.linspace(0.1, 10.3, 300)
    rng = np.random.default_rng(stroke_degree + n_rows)
    weights = rng.uniform(0.0, 1.5, (300, n_rows, 100))
    weights[:, :, 7] = 0.0  # a masked pixel
    data = rng.normal(100.0, 20.0, (300, n_rows, 100))
    factor = linear_fit._trig_stroke(model, x_mm)
    terms = factor.shape[-1]
    args = (factor.reshape(300, -1, terms), weights.reshape(300, -1), data.reshape(300, -1))
    sums = []
    for way in (linear_fit._compiled_frame_sums or linear_fit._frame_sums, linear_fit._frame_sums_numpy):
        gram, rhs = np.full((n_rows * 100, terms, terms), 1.0), np.full((n_rows * 100, terms), -1.0)  # added onto
        way(*args, gram, rhs)
        sums.append((gram, rhs))
    (gram, rhs), (expected_gram, expected_rhs) = sums
    assert np.abs(gram - expected_gram).max() < SUM_TOLERANCE * np.abs(expected_gram).max()
    assert np.abs(rhs - expected_rhs).max() < SUM_TOLERANCE * np.abs(expected_rhs).max()
    if kernels.COMPILED:  # the loop sums one triangle and mirrors it (numpy's products are symmetric to rounding)
        assert np.array_equal(gram, np.swapaxes(gram, -1, -2))
    assert np.array_equal(gram[7::100], np.ones((n_rows, terms, terms)))  # nothing from the masked pixel


def test_the_solved_coefficients_reproduce_a_models_frames() -> None:
    truth = _model(1, 2)
    coeffs = np.random.default_rng(3).normal(0.0, 1.0, truth.coeff_shape)
    coeffs[0, 0, 0, 0] = 100.0
    truth = truth.with_changes(coeffs=coeffs)
    x_mm = np.linspace(0.1, 10.3, 200)
    frames = truth.predict(x_mm, with_response=False)
    fitted, _ = linear_fit.fit_coefficients(truth.with_changes(coeffs=None), x_mm, frames, np.ones_like(frames))
    assert np.abs(fitted.coeffs - coeffs).max() < 1e-9


def test_the_sums_run_compiled_on_the_model_s_own_trig_terms_where_the_kernels_do(
        monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    if kernels.COMPILED:
        monkeypatch.setattr(linear_fit, "_compiled_frame_sums", lambda *args: calls.append("compiled"))
    monkeypatch.setattr(linear_fit, "_frame_sums_numpy", lambda *args: calls.append("numpy"))
    x_mm = np.linspace(0.1, 10.3, 30)
    for stroke_degree in (0, 1):  # the trig terms themselves (term-major), then their product with the stroke's
        data = np.ones((30, 2, 100))
        linear_fit.normal_equations(_model(stroke_degree, 2), x_mm, data, data)
    assert calls == (["compiled", "numpy"] if kernels.COMPILED else ["numpy", "numpy"])
