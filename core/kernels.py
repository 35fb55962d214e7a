"""The compiled kernel of the per-frame solve: a model's values, slopes and the solver's seven
moments at one position, for any model :class:`~graytrack.core.frame_tables.FrameTables` holds.

numba compiles it on first use (cached on disk next to this file); without numba, or with
``GRAYTRACK_KERNEL=numpy`` in the environment, :class:`TableEvaluator` uses the tables' numpy
evaluation, which gives the same numbers (tests/core/test_kernels.py holds them to 1e-9 µm).
Pixels are the innermost, contiguous loop so that the compiler vectorises across them, in blocks
whose sums stay in the first-level cache.
"""

from __future__ import annotations

import math
import os

import numpy as np

from graytrack.core.frame_tables import FrameTables

try:  # numba is a dependency; its absence (an exotic platform) costs speed, never numbers
    import numba
except ImportError:  # pragma: no cover - exercised through GRAYTRACK_KERNEL=numpy
    numba = None  # type: ignore[assignment]  # the kernels' callers check for None

COMPILED = numba is not None and os.environ.get("GRAYTRACK_KERNEL", "").lower() != "numpy"
BLOCK = 64  # pixels whose sums the kernel keeps together (1 KB: the first-level cache holds them)


def _evaluate_into(x: float, omega: float, c_re: np.ndarray, c_im: np.ndarray, offset: np.ndarray,
                   lo: float, hi: float, table: np.ndarray, map_base: np.ndarray, map_size: int, origin: float,
                   step: float, target_offset: np.ndarray,
                   clip_lo: float, clip_hi: float, values: np.ndarray, slopes: np.ndarray,
                   smooth: np.ndarray) -> None:
    """values, slopes (P,) at x; ``smooth`` is scratch (P,). Coefficients are in pixel blocks,
    (blocks, M+1, L, BLOCK) (:func:`blocked`); pixel p reads the map row starting at
    ``table[map_base[p]]`` (``map_size`` nodes a row)."""
    n_blocks, n_orders, n_stroke, block = c_re.shape
    n_values = offset.size
    z_re = np.empty(n_orders)
    z_im = np.empty(n_orders)
    for h in range(n_orders):
        angle = omega * (x * h)
        z_re[h] = math.cos(angle)
        z_im[h] = math.sin(angle)
    legendre = np.ones(n_stroke)
    dlegendre = np.zeros(n_stroke)
    if n_stroke > 1:
        s = (2.0 * x - (lo + hi)) * (1.0 / (hi - lo)) if hi > lo else 0.0
        legendre[1], dlegendre[1] = s, 1.0
        for n in range(2, n_stroke):
            legendre[n] = ((2 * n - 1) * s * legendre[n - 1] - (n - 1) * legendre[n - 2]) / n
            dlegendre[n] = n * legendre[n - 1] + s * dlegendre[n - 1]
        scale = 2.0 / (hi - lo) if hi > lo else 0.0
        for n in range(n_stroke):
            dlegendre[n] *= scale
    # value: Re(c·b·zʰ); slope: Re(c·(db + i·b·ωh)·zʰ): two products a coefficient, folded
    value_re = np.empty((n_stroke, n_orders))
    value_im = np.empty((n_stroke, n_orders))
    slope_re = np.empty((n_stroke, n_orders))
    slope_im = np.empty((n_stroke, n_orders))
    for n in range(n_stroke):
        b, db = legendre[n], dlegendre[n]
        for h in range(n_orders):
            zr, zi, turn = z_re[h], z_im[h], omega * h
            value_re[n, h], value_im[n, h] = b * zr, b * zi
            slope_re[n, h], slope_im[n, h] = db * zr - b * turn * zi, db * zi + b * turn * zr
    # A block's sums stay in the first-level cache while every coefficient of the block streams
    # past once (the coefficients of a 16-row model outgrow the second-level cache: pixel by pixel
    # over each coefficient row, the sums went back and forth to it, twice as slow).
    acc = np.empty(block)
    dacc = np.empty(block)
    for k in range(n_blocks):
        for q in range(block):
            acc[q] = 0.0
            dacc[q] = 0.0
        for h in range(n_orders):
            for n in range(n_stroke):
                vr, vi, sr, si = value_re[n, h], value_im[n, h], slope_re[n, h], slope_im[n, h]
                row_re, row_im = c_re[k, h, n], c_im[k, h, n]
                for q in range(block):
                    acc[q] += row_re[q] * vr - row_im[q] * vi
                    dacc[q] += row_re[q] * sr - row_im[q] * si
        first = k * block
        for q in range(min(block, n_values - first)):
            smooth[first + q] = acc[q]
            slopes[first + q] = dacc[q]
    last = map_size - 1
    if last > 0:  # the map's factor onto the sums, branch-free (selects): the compiler vectorises it
        for p in range(n_values):
            # (the numpy evaluation's own rounding: a node lands in the same cell, the same slope)
            position = (x + target_offset[p] - origin) / step
            cell = math.floor(position)
            inside = (cell >= 0.0) & (cell < last)
            at = int(cell) if inside else 0
            base = map_base[p]
            low = table[base + at]
            rise = table[base + at + 1] - low
            on_last = position == last
            factor = 1.0 + low + (position - at) * rise if inside else (
                1.0 + table[base + last] if on_last else 1.0)
            dfactor = rise / step if inside else 0.0
            slopes[p] = slopes[p] * factor + smooth[p] * dfactor
            smooth[p] = smooth[p] * factor
    for p in range(n_values):
        value = smooth[p] + offset[p]
        slope = slopes[p]
        if value <= clip_lo:
            value, slope = clip_lo, 0.0
        elif value >= clip_hi:
            value, slope = clip_hi, 0.0
        values[p] = value
        slopes[p] = slope


def _moments(x: float, y: np.ndarray, w: np.ndarray, omega: float, c_re: np.ndarray, c_im: np.ndarray,
             offset: np.ndarray, lo: float, hi: float, table: np.ndarray, map_base: np.ndarray, map_size: int,
             origin: float, step: float, target_offset: np.ndarray, clip_lo: float, clip_hi: float, scratch: np.ndarray,
             out: np.ndarray) -> None:
    """The seven moments (as FrameTables.moments) into ``out``; ``scratch`` is (3, P): the values and
    slopes at x are left in its first two rows."""
    values, slopes = scratch[0], scratch[1]
    _evaluate_into(x, omega, c_re, c_im, offset, lo, hi, table, map_base, map_size, origin, step, target_offset,
                   clip_lo, clip_hi, values, slopes, scratch[2])
    _reduce(values, slopes, y, w, out)


def _reduce(values: np.ndarray, slopes: np.ndarray, y: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """The seven moments of values and slopes already evaluated (``_moments`` without the evaluation)."""
    ff = fdf = dfdf = f1 = df1 = yf = ydf = 0.0
    for p in range(values.size):
        wv, ws = w[p] * values[p], w[p] * slopes[p]
        ff += wv * values[p]
        fdf += ws * values[p]
        dfdf += ws * slopes[p]
        f1 += wv
        df1 += ws
        yf += wv * y[p]
        ydf += ws * y[p]
    out[0], out[1], out[2], out[3], out[4], out[5], out[6] = ff, fdf, dfdf, f1, df1, yf, ydf


def _evaluate_many(x_mm: np.ndarray, omega: float, c_re: np.ndarray, c_im: np.ndarray, offset: np.ndarray,
                   lo: float, hi: float, table: np.ndarray, map_base: np.ndarray, map_size: int, origin: float,
                   step: float, target_offset: np.ndarray,
                   clip_lo: float, clip_hi: float, values: np.ndarray, slopes: np.ndarray,
                   smooth: np.ndarray) -> None:
    """values, slopes (G, P) at each of ``x_mm`` (G,)."""
    for g in range(x_mm.size):
        _evaluate_into(x_mm[g], omega, c_re, c_im, offset, lo, hi, table, map_base, map_size, origin, step,
                       target_offset, clip_lo, clip_hi, values[g], slopes[g], smooth)


if COMPILED:
    _evaluate_into = numba.njit(cache=True, nogil=True, error_model="numpy")(_evaluate_into)
    _evaluate_many = numba.njit(cache=True, nogil=True, error_model="numpy")(_evaluate_many)
    # the seven sums may be reassociated (vectorised): the same numbers to rounding, ~2x faster
    _reduce = numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc"})(_reduce)
    _moments = numba.njit(cache=True, nogil=True, error_model="numpy")(_moments)


def blocked(coefficients: np.ndarray) -> np.ndarray:
    """``(M+1, L, P)`` coefficients as ``(blocks, M+1, L, BLOCK)``: each block of pixels' coefficients
    contiguous, the last block padded with zeros."""
    n_orders, n_stroke, n_values = coefficients.shape
    n_blocks = -(-n_values // BLOCK)
    padded = np.zeros((n_orders, n_stroke, n_blocks * BLOCK))
    padded[..., :n_values] = coefficients
    return np.ascontiguousarray(padded.reshape(n_orders, n_stroke, n_blocks, BLOCK).transpose(2, 0, 1, 3))


class TableEvaluator:
    """Values, slopes and moments of a model from its frame tables: compiled, or numpy where
    numba is missing, the same numbers either way.

    The model at the last position evaluated is kept: a robust solve reads a frame's residuals at
    x and then solves again from that same x, and the moments there need only its reduction
    (the same numbers: the kept values are those the evaluation gives)."""

    def __init__(self, tables: FrameTables):
        self.tables = tables
        n_values = tables.n_values
        self._re = blocked(tables.coefficients.real)
        self._im = blocked(tables.coefficients.imag)
        lo, hi = tables.stroke_range_mm
        self._args = (tables.omega, self._re, self._im, tables.offset, lo, hi, tables.target_map, tables.map_base,
                      tables.map_size, tables.map_origin_mm, tables.map_step_mm, tables.target_offset_mm,
                      *tables.clip_gray)
        self._scratch = np.empty((3, n_values))
        self._at = float("nan")  # the position whose values and slopes _scratch[0], _scratch[1] hold
        self._out = np.empty(7)
        if COMPILED:  # compiled (or loaded from the disk cache) now, at model install, not on a live frame
            for _ in range(2):  # evaluated, then read again at the same position
                self.moments(0.0, np.zeros(n_values), np.zeros(n_values))
            self._at = float("nan")
            self.evaluate(np.zeros(1))
            self.evaluate(np.zeros(2))
            self._at = float("nan")

    def evaluate(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values and slopes ``(G, P)`` at positions ``x_mm`` ``(G,)``."""
        x_mm = np.atleast_1d(np.asarray(x_mm, dtype=np.float64))
        if not COMPILED:
            return self.tables.evaluate(x_mm)
        if x_mm.size == 1:
            x = float(x_mm[0])
            if x != self._at:  # (NaN: never kept)
                _evaluate_into(x, *self._args, self._scratch[0], self._scratch[1], self._scratch[2])
                self._at = x
            return self._scratch[0][None].copy(), self._scratch[1][None].copy()
        values, slopes = np.empty((x_mm.size, self.tables.n_values)), np.empty((x_mm.size, self.tables.n_values))
        _evaluate_many(x_mm, *self._args, values, slopes, self._scratch[2])
        return values, slopes

    def moments(self, x_mm: float, y: np.ndarray, w: np.ndarray) -> list[float]:
        """The solver's seven moments at ``x_mm`` for frame ``y`` under weights ``w`` (both ``(P,)``)."""
        if not COMPILED:
            return self.tables.moments(x_mm, y, w).tolist()
        x = float(x_mm)
        if x == self._at:
            _reduce(self._scratch[0], self._scratch[1], y, w, self._out)
        else:
            _moments(x, y, w, *self._args, self._scratch, self._out)
            self._at = x
        return self._out.tolist()
