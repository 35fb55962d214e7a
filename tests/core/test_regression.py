"""tall_least_squares (core/regression.py): numpy's lstsq answer on the closed loop's kind of basis (trig terms
times pixel polynomials, scaled columns near-orthogonal), and lstsq's own where the basis is nearly or wholly
dependent."""

from __future__ import annotations

import numpy as np

from graytrack.core.basis import legendre_basis, scaled, trig_basis
from graytrack.core.evidence import trig_times_pixel
from graytrack.core.regression import NORMAL_EQUATIONS_COND, tall_least_squares

# NORMAL_EQUATIONS_COND times the double rounding: what the normal equations may differ from lstsq by, relative
COEFFICIENT_TOLERANCE = NORMAL_EQUATIONS_COND * np.finfo(float).eps


def _probe_basis(frames: int = 200, pixels: int = 100, harmonics: int = 5, degree: int = 3) -> np.ndarray:
    """A pixel-polynomial probe's basis over a sweep: ``(frames·pixels, (2M+1)·degree)``."""
    x = np.linspace(0.0, 10.0, frames)[:, None, None] + 0.0054 * np.arange(pixels)[None, None, :]
    trig = trig_basis(2.0 * np.pi * x / 0.86, harmonics)
    pixel = legendre_basis(scaled(np.arange(pixels), 0, pixels - 1), degree)[:, 1:]
    return trig_times_pixel(trig, pixel).reshape(frames * pixels, -1)


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_a_probe_basis_gets_lstsqs_coefficients() -> None:
    basis = _probe_basis()
    rng = np.random.default_rng(5)
    values = basis @ rng.normal(0.0, 1.0, basis.shape[1]) + rng.normal(0.0, 3.0, basis.shape[0])
    values[::7] *= 1e3  # the scale of the answer does not matter, nor that it fits badly
    expected, *_ = np.linalg.lstsq(basis, values, rcond=None)
    assert _relative(tall_least_squares(basis, values), expected) < COEFFICIENT_TOLERANCE
    several = np.stack([values, -2.0 * values + 1.0], axis=1)  # several right-hand sides at once
    expected, *_ = np.linalg.lstsq(basis, several, rcond=None)
    assert _relative(tall_least_squares(basis, several), expected) < COEFFICIENT_TOLERANCE


def test_columns_of_very_different_scales_are_scaled_first() -> None:
    scales = np.logspace(-4, 4, 33)
    basis = _probe_basis() * scales  # condition ~1e8 raw, the probe's own once its columns are scaled
    values = np.random.default_rng(6).normal(0.0, 1.0, basis.shape[0])
    expected, *_ = np.linalg.lstsq(basis / scales, values, rcond=None)  # lstsq loses 1e-8 of it on the raw basis
    assert _relative(tall_least_squares(basis, values) * scales, expected) < COEFFICIENT_TOLERANCE


def test_a_dependent_or_empty_column_gets_lstsqs_minimum_norm_answer() -> None:
    basis = _probe_basis(frames=40)
    values = np.random.default_rng(7).normal(0.0, 1.0, basis.shape[0])
    for broken in (np.column_stack([basis, basis[:, 3] + 1e-9 * basis[:, 4]]),  # nearly a copy of a column
                   np.column_stack([basis, np.zeros(len(basis))])):  # a probe term no sample carries
        expected, *_ = np.linalg.lstsq(broken, values, rcond=None)
        assert np.array_equal(tall_least_squares(broken, values), expected)
