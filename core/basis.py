"""Basis functions shared by the models: harmonics of the target phase and Legendre polynomials.

Polynomials are taken in a coordinate scaled to [-1, 1] (pixel index, row index, stroke position)
and in the Legendre basis: with the raw pixel index the normal matrix of a cubic spans twelve
orders of magnitude, with scaled Legendre polynomials it is close to diagonal.
"""

from __future__ import annotations

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
    per point whatever M is. The terms are built term-major (each one contiguous, which is what
    makes the recurrence fast on large strips) and returned as a view with the term axis last.
    """
    phase = np.asarray(phase, dtype=np.float64)
    out = np.empty((2 * harmonics + 1,) + phase.shape)
    out[0] = 1.0
    if harmonics:
        np.sin(phase, out=out[1])
        np.cos(phase, out=out[2])
        s1, c1 = out[1], out[2]
        for h in range(2, harmonics + 1):
            s_prev, c_prev = out[2 * h - 3], out[2 * h - 2]
            np.multiply(s_prev, c1, out=out[2 * h - 1])
            out[2 * h - 1] += c_prev * s1
            np.multiply(c_prev, c1, out=out[2 * h])
            out[2 * h] -= s_prev * s1
    return np.moveaxis(out, 0, -1)


def trig_derivative(trig: np.ndarray, harmonics: int) -> np.ndarray:
    """d/dθ of :func:`trig_basis` given its value: (sin hθ)' = h cos hθ, (cos hθ)' = -h sin hθ."""
    out = np.zeros_like(trig)
    h = np.arange(1, harmonics + 1, dtype=np.float64)
    out[..., 1::2] = h * trig[..., 2::2]
    out[..., 2::2] = -h * trig[..., 1::2]
    return out
