"""Basis functions shared by the models: harmonics of the target phase and Legendre polynomials.

Polynomials are taken in a coordinate scaled to [-1, 1] (pixel index, row index, stroke position)
and in the Legendre basis: with the raw pixel index the normal matrix of a cubic spans twelve
orders of magnitude, with scaled Legendre polynomials it is close to diagonal.
"""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np
from numpy.polynomial import legendre


def scaled(index: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Map ``[lo, hi]`` onto ``[-1, 1]``; a degenerate range maps to 0."""
    index = np.asarray(index, dtype=np.float64)
    if hi <= lo:
        return np.zeros_like(index)
    return (2.0 * index - (lo + hi)) / (hi - lo)


def legendre_basis(s: np.ndarray, degree: int) -> np.ndarray:
    """``(..., degree + 1)`` Legendre polynomials P_0..P_degree at scaled coordinates ``s``."""
    return legendre.legvander(np.asarray(s, dtype=np.float64), degree)


def trig_basis(phase: np.ndarray, harmonics: int) -> np.ndarray:
    """``(..., 2M + 1)``: ``[1, sin θ, cos θ, sin 2θ, cos 2θ, …, sin Mθ, cos Mθ]``.

    Higher harmonics come from the angle-addition recurrence, so one sin/cos pair is evaluated
    per point whatever M is. The terms are built term-major (each one contiguous) and returned as
    a view with the term axis last. The recurrence runs compiled, one pass over the points that
    keeps each point's terms in registers (numpy's term-by-term passes wrote and read every term
    of every point three times, and the closed loop builds these for every geometry it tries);
    both ways give the same bits (tests/core/test_basis.py).
    """
    phase = np.asarray(phase, dtype=np.float64)
    out = np.empty((2 * harmonics + 1,) + phase.shape)
    out[0] = 1.0
    if harmonics:
        np.sin(phase, out=out[1])
        np.cos(phase, out=out[2])
        if harmonics > 1:
            compiled = _compiled_harmonics()
            terms = out.reshape(out.shape[0], -1)
            (compiled or _harmonics_numpy)(terms, harmonics)
    return np.moveaxis(out, 0, -1)


def _harmonics_loop(terms: np.ndarray, harmonics: int) -> np.ndarray:
    """Rows 3… of ``terms`` ``(2M + 1, points)`` from rows 1 and 2 (sin θ, cos θ), point by point:
    sin hθ = sin (h−1)θ·cos θ + cos (h−1)θ·sin θ, cos hθ = cos (h−1)θ·cos θ − sin (h−1)θ·sin θ."""
    for point in range(terms.shape[1]):
        s1, c1 = terms[1, point], terms[2, point]
        s, c = s1, c1
        for h in range(2, harmonics + 1):
            s, c = s * c1 + c * s1, c * c1 - s * s1
            terms[2 * h - 1, point] = s
            terms[2 * h, point] = c
    return terms


def _harmonics_numpy(terms: np.ndarray, harmonics: int) -> np.ndarray:
    """:func:`_harmonics_loop` term by term in numpy, the same operations in the same order
    (without numba, or with ``GRAYTRACK_KERNEL=numpy``)."""
    s1, c1 = terms[1], terms[2]
    for h in range(2, harmonics + 1):
        s_prev, c_prev = terms[2 * h - 3], terms[2 * h - 2]
        np.multiply(s_prev, c1, out=terms[2 * h - 1])
        terms[2 * h - 1] += c_prev * s1
        np.multiply(c_prev, c1, out=terms[2 * h])
        terms[2 * h] -= s_prev * s1
    return terms


@functools.cache
def _compiled_harmonics() -> Callable[[np.ndarray, int], np.ndarray] | None:
    """:func:`_harmonics_loop` compiled on first use (cached on disk next to this file), or None where
    the kernels run in numpy. Looked up here, not at import: graytrack.core.kernels imports the
    models, which import this module."""
    from graytrack.core import kernels

    if not kernels.COMPILED:
        return None
    return kernels.numba.njit(cache=True, nogil=True)(_harmonics_loop)


def trig_derivative(trig: np.ndarray, harmonics: int) -> np.ndarray:
    """d/dθ of :func:`trig_basis` given its value: (sin hθ)' = h cos hθ, (cos hθ)' = -h sin hθ.

    Term by term into an array of ``trig``'s memory order (term-major from :func:`trig_basis`: each
    term one contiguous pass), not through every other term's strided copy."""
    out = np.empty_like(trig)
    out[..., 0] = 0.0
    for h in range(1, harmonics + 1):
        np.multiply(trig[..., 2 * h], float(h), out=out[..., 2 * h - 1])
        np.multiply(trig[..., 2 * h - 1], -float(h), out=out[..., 2 * h])
    return out
