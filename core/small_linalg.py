"""Solves of the few-unknown systems every frame's nuisances need (light, field, focus: 2–6 unknowns).

``numpy.linalg.solve`` spends ~20–40 µs per call on dispatch and checks for a 3×3 system, which a
frame pays a dozen times when its light or focus is solved. Gaussian elimination with partial
pivoting, compiled, does it in well under a microsecond, with the same answer to rounding; without
numba (or GRAYTRACK_KERNEL=numpy) numpy's own solver is used.
"""

from __future__ import annotations

import numpy as np

from graytrack.core import kernels

_SINGULAR = 1e-300


def _eliminate(a: np.ndarray, b: np.ndarray) -> bool:
    """Solve ``a x = b`` in place (``b`` (n, m) becomes x); False when ``a`` is singular."""
    n = a.shape[0]
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if abs(a[pivot, col]) < _SINGULAR:
            return False
        if pivot != col:
            for k in range(n):
                a[col, k], a[pivot, k] = a[pivot, k], a[col, k]
            for k in range(b.shape[1]):
                b[col, k], b[pivot, k] = b[pivot, k], b[col, k]
        for row in range(col + 1, n):
            factor = a[row, col] / a[col, col]
            if factor != 0.0:
                for k in range(col, n):
                    a[row, k] -= factor * a[col, k]
                for k in range(b.shape[1]):
                    b[row, k] -= factor * b[col, k]
    for col in range(n - 1, -1, -1):
        for k in range(b.shape[1]):
            total = b[col, k]
            for j in range(col + 1, n):
                total -= a[col, j] * b[j, k]
            b[col, k] = total / a[col, col]
    return True


if kernels.COMPILED:
    _eliminate = kernels.numba.njit(cache=True, nogil=True)(_eliminate)


def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``numpy.linalg.solve`` for one small system (``b`` a vector or a matrix)."""
    if not kernels.COMPILED:
        return np.linalg.solve(a, b)
    work = np.array(a, dtype=np.float64)
    rhs = np.array(b, dtype=np.float64)
    columns = rhs.reshape(rhs.shape[0], -1)
    if not _eliminate(work, columns):
        raise np.linalg.LinAlgError("Singular matrix")
    return columns.reshape(rhs.shape)


def inv(a: np.ndarray) -> np.ndarray:
    """``numpy.linalg.inv`` of one small matrix."""
    return solve(a, np.eye(np.shape(a)[0]))


def warm() -> None:
    """Compile (or load from numba's cache) the elimination now: a tracker's first light-field or
    focus frame must not wait for the compiler."""
    inv(np.eye(3))
