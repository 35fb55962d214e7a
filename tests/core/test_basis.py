"""The trig basis (core/basis.py): the compiled recurrence gives numpy's terms to the bit, and both
are the harmonics' sines and cosines to the recurrence's rounding."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core import basis, kernels

# What M angle additions round to (each a few ulp of a term bounded by 1): far below any fit's noise.
RECURRENCE_TOLERANCE = 1e-13


def _numpy_terms(phase: np.ndarray, harmonics: int) -> np.ndarray:
    """trig_basis with the recurrence done by numpy term by term (as GRAYTRACK_KERNEL=numpy runs it)."""
    out = np.empty((2 * harmonics + 1,) + phase.shape)
    out[0] = 1.0
    if harmonics:
        np.sin(phase, out=out[1])
        np.cos(phase, out=out[2])
        basis._harmonics_numpy(out.reshape(out.shape[0], -1), harmonics)
    return np.moveaxis(out, 0, -1)


@pytest.mark.parametrize("shape", [(7,), (300, 16, 100), (5, 1, 33)])
@pytest.mark.parametrize("harmonics", [0, 1, 2, 5, 9])
def test_the_compiled_recurrence_gives_numpys_terms_and_the_harmonics(shape: tuple[int, ...], harmonics: int) -> None:
    phase = np.random.default_rng(len(shape) + harmonics).uniform(-40.0, 40.0, shape)
    terms = basis.trig_basis(phase, harmonics)
    assert terms.shape == shape + (2 * harmonics + 1,)
    assert np.array_equal(terms, _numpy_terms(phase, harmonics))
    h = np.arange(1, harmonics + 1)
    assert np.all(terms[..., 0] == 1.0)
    assert np.abs(terms[..., 1::2] - np.sin(phase[..., None] * h)).max(initial=0.0) < RECURRENCE_TOLERANCE
    assert np.abs(terms[..., 2::2] - np.cos(phase[..., None] * h)).max(initial=0.0) < RECURRENCE_TOLERANCE


def test_a_strided_phase_is_read_as_its_values() -> None:
    phase = np.linspace(0.0, 30.0, 600).reshape(20, 30)
    assert np.array_equal(basis.trig_basis(phase[:, ::3], 5), basis.trig_basis(phase[:, ::3].copy(), 5))
    assert np.array_equal(basis.trig_basis(phase.T, 5), _numpy_terms(phase.T, 5))


def test_the_recurrence_runs_compiled_where_the_kernels_do() -> None:
    assert (basis._compiled_harmonics() is not None) == kernels.COMPILED


@pytest.mark.parametrize("harmonics", [1, 5])
def test_the_derivative_is_each_harmonics_in_either_memory_order(harmonics: int) -> None:
    phase = np.random.default_rng(harmonics).uniform(-40.0, 40.0, (30, 4, 25))
    terms = basis.trig_basis(phase, harmonics)
    derivative = basis.trig_derivative(terms, harmonics)
    assert np.array_equal(derivative, basis.trig_derivative(np.ascontiguousarray(terms), harmonics))
    h = np.arange(1, harmonics + 1)
    assert np.all(derivative[..., 0] == 0.0)
    assert np.abs(derivative[..., 1::2] - h * np.cos(phase[..., None] * h)).max() < harmonics * RECURRENCE_TOLERANCE
    assert np.abs(derivative[..., 2::2] + h * np.sin(phase[..., None] * h)).max() < harmonics * RECURRENCE_TOLERANCE
