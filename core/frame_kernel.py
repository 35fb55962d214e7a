"""The per-frame solve as one call: Gauss–Newton with the light's gain and offset, the robust
reweighting with its blob (transient) rejection and bad-pixel masks, and the frame's bound, on a
model's precomputed tables.

The control logic is written once, here, in the subset of Python and numpy that numba compiles:
with numba it runs compiled on the tables of :class:`~graytrack.core.kernels.TableEvaluator`
(one call per solve: no Python between iterations); without it (or with ``GRAYTRACK_KERNEL=numpy``,
or for an evaluator that is no table kernel: a model's own ``predict``) the very same functions
run as Python, their few pixel-level primitives bound to numpy ones (:func:`_python_twin`):

    _model_at     values and slopes at one position   (compiled: the kernel's loop; else ``evaluate``)
    _moments_of   the seven moments of those           (compiled: the kernel's loop; else numpy dots)
    _scalars_of   Σw·y², Σw·y, Σw, samples used        (compiled: one loop; else numpy sums)
    _blob_samples compact blobs in one frame           (compiled: the flood fill; else scipy's labels)

The solver's algebra (:func:`light_step`) is shared with the moment-source solver of
core/solvers.py, and tests/core/test_frame_kernel.py holds both modes to the same positions
(1e-9 µm) on frames with each effect family.
"""

from __future__ import annotations

import cmath
import math
import types

import numpy as np

from graytrack.core import kernels, small_linalg, transients
from graytrack.core.pixel_noise import _MIN_VARIANCE_GRAY2 as _MIN_VARIANCE

CORE_SIGMA, CUT_SIGMA = 3.5, 7.0  # redescending weight: full inside the core, none beyond the cut (robust σ)
ROBUST_ITERATIONS = 6
MAD_TO_SIGMA = 1.4826
# A blob up to half the line wide is still set aside as one transient in tracking (the frame is then
# unlocked when it loses too much, with the transient as the reason); a wider change is the light's.
TRANSIENT_MAX_WIDTH_SHARE = 0.5
# What a solve writes into its ``out`` row (one float array: no objects cross the compiled boundary).
FIELDS = ("x", "iterations", "information", "gain", "offset", "cost", "chi2", "excess", "rejected", "exact",
          "transient_px", "transient_share", "transient_at", "at", "masked")
N_FIELDS = len(FIELDS)
GROW_Z, MIN_SAMPLES, MARGIN_PX = transients.GROW_Z, transients.MIN_SAMPLES, transients.MARGIN_PX
_flood_blobs = transients._compiled_blobs  # the flood fill (compiled where numba is)


def light_step(ff: float, fdf: float, dfdf: float, f1: float, df1: float, yf: float, ydf: float,
               yy: float, y1: float, s11: float, free: bool) -> tuple[float, float, float, float, float]:
    """(numerator, information, gain, offset, cost) of the Gauss–Newton step in x at these moments.

    With free light the gain and offset are profiled out (their LS values at this x) and the
    information is the Schur complement: what is left for x once g and o are estimated too."""
    gain, offset, det = 1.0, 0.0, 0.0
    if free:
        det = ff * s11 - f1 * f1
        if det <= 0.0:
            det = 0.0
        else:
            gain, offset = (yf * s11 - f1 * y1) / det, (ff * y1 - f1 * yf) / det
    numerator = gain * (ydf - gain * fdf - offset * df1)
    information = gain * gain * dfdf
    if det > 0.0:
        a, b = gain * fdf, gain * df1
        information -= (a * a * s11 - 2.0 * a * b * f1 + b * b * ff) / det
    cost = (yy - 2.0 * gain * yf - 2.0 * offset * y1
            + gain * gain * ff + 2.0 * gain * offset * f1 + offset * offset * s11)
    return numerator, information, gain, offset, cost


_light_step = light_step  # what the control functions call (compiled with them)


# --------------------------------------------------------------------------- pixel-level primitives
def _model_at(x: float, model: tuple, scratch: np.ndarray) -> None:
    """Values and slopes at ``x`` into ``scratch[0]``, ``scratch[1]`` (``scratch[2]``: work)."""
    kernels._evaluate_into(x, *model, scratch[0], scratch[1], scratch[2])


def _moments_of(values: np.ndarray, slopes: np.ndarray, y: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    kernels._reduce(values, slopes, y, w, out)


def _scalars_of(y: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """Σw·y², Σw·y, Σw and the number of samples with weight into ``out``."""
    yy = y1 = total = count = 0.0
    for p in range(y.size):
        wy = w[p] * y[p]
        yy += wy * y[p]
        y1 += wy
        total += w[p]
        count += 1.0 if w[p] > 0.0 else 0.0
    out[0], out[1], out[2], out[3] = yy, y1, total, count


def _blob_samples(size: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The samples of compact blobs (core/transients.py) in one frame's normalised residual ``(R·n,)``."""
    out = np.zeros((1, rows, cols), dtype=np.bool_)
    _flood_blobs(size.reshape((1, rows, cols)), CUT_SIGMA, GROW_Z, max(TRANSIENT_MAX_WIDTH_SHARE * cols, 3.0),
                 MIN_SAMPLES, MARGIN_PX, out)
    return out.reshape(rows * cols)


def _sizes(y: np.ndarray, values: np.ndarray, gain: float, offset: float, root: np.ndarray,
           size: np.ndarray) -> None:
    """The residuals' sizes in their own σ, ``|y − g·F − o|·√w``, into ``size``."""
    for p in range(y.size):
        size[p] = abs((y[p] - gain * values[p] - offset) * root[p])


def _upper_median(size: np.ndarray, used: np.ndarray, masked: bool, work: np.ndarray) -> float:
    """The upper median of ``size`` (over the ``used`` samples when ``masked``) by an in-place
    quickselect on ``work``: the order statistic ``np.partition`` gives, with no allocation."""
    n = 0
    for p in range(size.size):
        if not masked or used[p]:
            work[n] = size[p]
            n += 1
    if n == 0:
        return 0.0
    k = n // 2
    lo, hi = 0, n - 1
    while lo < hi:
        pivot = work[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while work[i] < pivot:
                i += 1
            while work[j] > pivot:
                j -= 1
            if i <= j:
                work[i], work[j] = work[j], work[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return work[k]


def _normalise_and_cut(size: np.ndarray, factor: float, rejected: np.ndarray) -> bool:
    """``size`` scaled by ``factor`` in place, ``rejected`` = beyond the cut; True when any is.
    (Branch-free, so that the compiler vectorises it.)"""
    count = 0
    for p in range(size.size):
        value = size[p] * factor
        size[p] = value
        beyond = value >= CUT_SIGMA
        rejected[p] = beyond
        count += beyond
    return count > 0


def _settle_classes(size: np.ndarray, rejected: np.ndarray, before: np.ndarray, used: np.ndarray,
                    masked: bool, have_before: bool) -> tuple[bool, bool, float]:
    """Masked samples out of ``rejected`` (in place); (tapered: a kept sample beyond the core,
    same: the set rejected is ``before``'s, the count rejected). Branch-free, as above."""
    keep_all = not masked
    count = tapered = changed = 0
    for p in range(size.size):
        out = rejected[p] & (used[p] | keep_all)
        rejected[p] = out
        count += out
        tapered += (not out) & (size[p] > CORE_SIGMA)
        changed += out != before[p]
    return tapered > 0, have_before and changed == 0, float(count)


def _robust_weights(size: np.ndarray, rejected: np.ndarray, w: np.ndarray, tapered: bool, out: np.ndarray) -> None:
    """The redescending weights: ``w`` inside the core, Tukey's taper to 0 at the cut (when any
    kept sample is in it), 0 on the rejected."""
    span = 1.0 / (CUT_SIGMA - CORE_SIGMA)
    for p in range(size.size):
        if rejected[p]:
            out[p] = 0.0
        elif tapered:
            t = min(max((size[p] - CORE_SIGMA) * span, 0.0), 1.0)
            factor = 1.0 - t * t
            out[p] = w[p] * (factor * factor)
        else:
            out[p] = w[p]


def _numpy_sizes(y: np.ndarray, values: np.ndarray, gain: float, offset: float, root: np.ndarray,
                 size: np.ndarray) -> None:
    np.abs((y - gain * values - offset) * root, out=size)


def _numpy_upper_median(size: np.ndarray, used: np.ndarray, masked: bool, work: np.ndarray) -> float:
    return _middle(size[used] if masked else size)


def _numpy_normalise_and_cut(size: np.ndarray, factor: float, rejected: np.ndarray) -> bool:
    size *= factor
    np.greater_equal(size, CUT_SIGMA, out=rejected)
    return bool(rejected.any())


def _numpy_settle_classes(size: np.ndarray, rejected: np.ndarray, before: np.ndarray, used: np.ndarray,
                          masked: bool, have_before: bool) -> tuple[bool, bool, float]:
    if masked:
        rejected &= used
    tapered = bool((size[~rejected] > CORE_SIGMA).any())
    same = have_before and not bool((rejected ^ before).any())
    return tapered, same, float(np.count_nonzero(rejected))


def _numpy_robust_weights(size: np.ndarray, rejected: np.ndarray, w: np.ndarray, tapered: bool,
                          out: np.ndarray) -> None:
    if tapered:
        t = np.minimum(np.maximum((size - CORE_SIGMA) * (1.0 / (CUT_SIGMA - CORE_SIGMA)), 0.0), 1.0)
        factor = 1.0 - t * t
        out[:] = w * np.where(rejected, 0.0, factor * factor)
    else:
        out[:] = np.where(rejected, 0.0, w)


def _numpy_model_at(x: float, model: tuple, scratch: np.ndarray) -> None:
    values, slopes = model[0].evaluate(np.array([x]))
    scratch[0], scratch[1] = values[0], slopes[0]


def _numpy_moments_of(values: np.ndarray, slopes: np.ndarray, y: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    wv, ws = values * w, slopes * w
    out[:] = (wv @ values, ws @ values, ws @ slopes, wv.sum(), ws.sum(), wv @ y, ws @ y)


def _numpy_scalars_of(y: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    weighted = w * y
    out[:] = (weighted @ y, weighted.sum(), w.sum(), np.count_nonzero(w > 0.0))


def _numpy_blob_samples(size: np.ndarray, rows: int, cols: int) -> np.ndarray:
    return transients._scipy_blobs(size.reshape((1, rows, cols)), CUT_SIGMA, GROW_Z,
                                   TRANSIENT_MAX_WIDTH_SHARE).reshape(-1)


# --------------------------------------------------------------------------- the control logic (written once)
def _middle(values: np.ndarray) -> float:
    """The (upper) median by one partial sort."""
    if values.size == 0:
        return 0.0
    half = values.size // 2
    return float(np.partition(values, half)[half])


def _gauss_newton(y: np.ndarray, w: np.ndarray, x: float, free: bool, max_iterations: int, tolerance: float,
                  max_step: float, model: tuple, scratch: np.ndarray, at: float, moments: np.ndarray,
                  scalars: np.ndarray) -> tuple:
    """Weighted Gauss–Newton from ``x``; gain/offset profiled when ``free``. ``scratch`` holds the
    model at ``at`` (NaN: nothing). Returns (x, iterations, information, gain, offset, cost, χ²,
    light excess, at)."""
    _scalars_of(y, w, scalars)
    yy, y1, s11, count = scalars[0], scalars[1], scalars[2], scalars[3]
    information, gain, offset, cost = 0.0, 1.0, 0.0, math.inf
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        if x != at:
            _model_at(x, model, scratch)
            at = x
        _moments_of(scratch[0], scratch[1], y, w, moments)
        numerator, information, gain, offset, cost = _light_step(
            moments[0], moments[1], moments[2], moments[3], moments[4], moments[5], moments[6], yy, y1, s11, free)
        dx = numerator / information if information > 0.0 else 0.0
        dx = min(max(dx, -max_step), max_step)
        x += dx
        if abs(dx) < tolerance:
            break
    chi2, excess = _fit_figures(cost, count, free, yy, moments)
    return x, iterations, information, gain, offset, cost, chi2, excess, at


def _fit_figures(cost: float, count: float, free: bool, yy: float, moments: np.ndarray) -> tuple[float, float]:
    """(χ² per degree of freedom, the χ² the free light gained) at the last evaluated point: the
    final step is below tolerance."""
    n_used = max(count - (2.0 if free else 0.0) - 1.0, 1.0)
    chi2 = max(cost, 0.0) / n_used
    excess = yy - 2.0 * moments[5] + moments[0] - cost if free else 0.0
    return chi2, excess


def _row_moments(rows: np.ndarray, orders: np.ndarray, x: float, out: np.ndarray) -> None:
    """The seven moments of a moment-table source (the trig-polynomial fast path, core/solvers.py):
    Re Σ_j rows[:, j]·e^{orders_j·x}, with ``orders`` = iωj."""
    for i in range(7):
        out[i] = 0.0
    for j in range(orders.size):
        z = cmath.exp(orders[j] * x)
        for i in range(7):
            out[i] += (rows[i, j] * z).real


def _numpy_row_moments(rows: np.ndarray, orders: np.ndarray, x: float, out: np.ndarray) -> None:
    out[:] = rows.dot(np.exp(orders * x)).real


def _rows_solve_into(rows: np.ndarray, orders: np.ndarray, yy: float, y1: float, s11: float, count: float,
                     x: float, free: bool, max_iterations: int, tolerance: float, max_step: float,
                     moments: np.ndarray, out: np.ndarray) -> None:
    """:func:`_gauss_newton` on a frame's moment rows ``(7, D+1)`` and scalars (Σw·y², Σw·y, Σw, samples
    used) instead of its pixels, the answer in ``out`` (:data:`FIELDS`): one call a frame where the
    Python loop spent ~10 µs on small numpy products."""
    information, gain, offset, cost = 0.0, 1.0, 0.0, math.inf
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        _row_moments(rows, orders, x, moments)
        numerator, information, gain, offset, cost = _light_step(
            moments[0], moments[1], moments[2], moments[3], moments[4], moments[5], moments[6], yy, y1, s11, free)
        dx = numerator / information if information > 0.0 else 0.0
        dx = min(max(dx, -max_step), max_step)
        x += dx
        if abs(dx) < tolerance:
            break
    chi2, excess = _fit_figures(cost, count, free, yy, moments)
    out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7] = \
        x, iterations, information, gain, offset, cost, chi2, excess
    out[8], out[9], out[10], out[11], out[12], out[13], out[14] = 0.0, 1.0, 0.0, 0.0, math.nan, math.nan, 0.0


def _solve_into(y: np.ndarray, w: np.ndarray, x: float, free: bool, max_iterations: int, tolerance: float,
                max_step: float, model: tuple, scratch: np.ndarray, at: float, moments: np.ndarray,
                scalars: np.ndarray, out: np.ndarray) -> None:
    """:func:`_gauss_newton` with its answer in ``out`` (see :data:`FIELDS`)."""
    x, iterations, information, gain, offset, cost, chi2, excess, at = _gauss_newton(
        y, w, x, free, max_iterations, tolerance, max_step, model, scratch, at, moments, scalars)
    out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7] = \
        x, iterations, information, gain, offset, cost, chi2, excess
    out[8], out[9], out[10], out[11], out[12], out[13], out[14] = 0.0, 1.0, 0.0, 0.0, math.nan, at, 0.0


def _may_be_blob(rejected: np.ndarray, size: np.ndarray, rows: int, cols: int) -> bool:
    """A rejected sample with a neighbour beyond the blob threshold: the blob search may find one
    (a lone stuck pixel, the usual rejection, skips it). Visits the rejected samples only."""
    for p in range(rejected.size):
        if not rejected[p]:
            continue
        row, col = p // cols, p % cols
        if (col > 0 and size[p - 1] > GROW_Z) or (col < cols - 1 and size[p + 1] > GROW_Z):
            return True
        if (row > 0 and size[p - cols] > GROW_Z) or (row < rows - 1 and size[p + cols] > GROW_Z):
            return True
    return False


def _numpy_may_be_blob(rejected: np.ndarray, size: np.ndarray, rows: int, cols: int) -> bool:
    if not rejected.any():
        return False
    near = (size > GROW_Z).reshape((rows, cols))
    out = rejected.reshape((rows, cols))
    if (out[:, :-1] & near[:, 1:]).any() or (out[:, 1:] & near[:, :-1]).any():
        return True
    return rows > 1 and bool((out[:-1] & near[1:]).any() or (out[1:] & near[:-1]).any())


def _mark_transient(samples: np.ndarray, cols: int, out: np.ndarray) -> None:
    """Count the samples set aside as a transient, their share and mean column, into ``out``."""
    where = np.flatnonzero(samples)
    count = where.size
    out[10] = count
    out[11] = count / samples.size if count else 0.0
    out[12] = float((where % cols).sum()) / count if count and cols > 0 else math.nan


def _robust(y: np.ndarray, w: np.ndarray, x: float, gain: float, offset: float, free: bool,
            start_mask: np.ndarray, use_start: bool, chi2_limit: float, rows: int, cols: int,
            max_iterations: int, tolerance: float, max_step: float, model: tuple, scratch: np.ndarray, at: float,
            moments: np.ndarray, scalars: np.ndarray, out: np.ndarray, mask: np.ndarray) -> None:
    """Iteratively reweighted least squares with a redescending weight on the normalised residuals
    (see :func:`graytrack.core.solvers.robust_solve`); the answer in ``out`` (:data:`FIELDS`) and the
    samples set aside in ``mask``. ``cols`` 0: no blob search (no layout)."""
    out[:] = 0.0
    out[12] = math.nan
    have_before = False
    before = np.zeros(y.size, dtype=np.bool_)
    exact = True
    if use_start:
        weights = np.where(start_mask, 0.0, w)
        x, iterations, information, gain, offset, cost, chi2, excess, at = _gauss_newton(
            y, weights, x, free, max_iterations, tolerance, max_step, model, scratch, at, moments, scalars)
        out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7] = \
            x, iterations, information, gain, offset, cost, chi2, excess
        out[8], out[9], out[14] = np.count_nonzero(start_mask), 1.0, 1.0
        before[:] = start_mask
        have_before = True
        if chi2 <= chi2_limit:  # the kept pixels fit: are the ones set aside still outliers?
            if not abs(x - at) < tolerance:  # (the last point evaluated is as good within the tolerance)
                _model_at(x, model, scratch)
                at = x
            pixels = np.flatnonzero(start_mask)
            smallest = CUT_SIGMA
            if pixels.size:
                smallest = (np.abs(y[pixels] - gain * scratch[0][pixels] - offset) * np.sqrt(w[pixels])).min()
            if smallest >= CUT_SIGMA:  # a bad pixel that stays bad: one masked solve, nothing else
                mask[:] = start_mask
                out[13] = at
                return
    root = np.sqrt(w)
    used = w > 0.0
    masked_pixels = not used.all()
    size = np.empty(y.size)
    work = np.empty(y.size)
    weights = np.empty(y.size)
    rejected = np.empty(y.size, dtype=np.bool_)
    for _ in range(ROBUST_ITERATIONS):
        # Each round starts where the model was last evaluated when that is within the solver's
        # tolerance of x (a converged solve's last step is below it): the residuals there are as
        # good, and the round's first Gauss–Newton step takes that small step too. One evaluation
        # of the model less per round; on a 16-row strip with dust, 7 → 4 a robust frame.
        if abs(x - at) < tolerance:
            x = at
        else:
            _model_at(x, model, scratch)
            at = x
        _sizes(y, scratch[0], gain, offset, root, size)
        scale = _upper_median(size, used, masked_pixels, work)
        any_rejected = _normalise_and_cut(size, 1.0 / max(1.0, MAD_TO_SIGMA * scale), rejected)
        blob_found = False
        blob = before
        if cols > 0 and any_rejected and _may_be_blob(rejected, size, rows, cols):
            blob = _blob_samples(size, rows, cols)
            rejected |= blob
            blob_found = True
        tapered, same, n_rejected = _settle_classes(size, rejected, before, used, masked_pixels, have_before)
        if not tapered and same and exact:
            out[10], out[11], out[12] = 0.0, 0.0, math.nan
            if blob_found:
                _mark_transient(blob & rejected, cols, out)
            break  # the last solve already used these weights
        _robust_weights(size, rejected, w, tapered, weights)
        x_new, iterations, information, gain, offset, cost, chi2, excess, at = _gauss_newton(
            y, weights, x, free, max_iterations, tolerance, max_step, model, scratch, at, moments, scalars)
        out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7] = \
            x_new, iterations, information, gain, offset, cost, chi2, excess
        out[8], out[9], out[14] = n_rejected, 0.0 if tapered else 1.0, 1.0
        exact = not tapered
        out[10], out[11], out[12] = 0.0, 0.0, math.nan
        if blob_found:
            _mark_transient(blob & rejected, cols, out)
        # Tapered weights follow the residuals, which follow x: the same set out and x still within
        # the solver's tolerance is the fixed point.
        settled = same and abs(x_new - x) < tolerance
        x = x_new
        before, rejected = rejected, before  # the old set's buffer takes the next one
        have_before = True
        if settled:
            break
    mask[:] = before
    out[13] = at


def _sample_weights(y: np.ndarray, fixed_var: float, shot_gain: float, dark_gray: float, floor_var: float,
                    pixel_weight: np.ndarray, rows: float, lo: float, hi: float, out: np.ndarray) -> bool:
    """1/σ² of samples ``y`` (any frames, flattened, ``pixel_weight`` tiled to them) under the
    photon-transfer model (core/pixel_noise.py, ``fixed_var`` = read + quantisation variance), times
    the pixel's weight and the rows averaged, 0 at the sensor's limits ``lo``/``hi``, into ``out``;
    True when no sample is at a limit. The numbers of ``model.inverse_variance(y) * rows``."""
    signal = np.maximum(y - dark_gray, 0.0)
    weights = 1.0 / np.maximum(fixed_var + shot_gain * signal, floor_var) * pixel_weight * rows
    if not lo < hi:  # no limits to check (NaN: none given)
        out[:] = weights
        return True
    inside = (y > lo) & (y < hi)
    shared = bool(inside.all())
    if shared:
        out[:] = weights
    else:
        out[:] = weights * inside
    return shared


def _sample_weights_loop(y: np.ndarray, fixed_var: float, shot_gain: float, dark_gray: float, floor_var: float,
                         pixel_weight: np.ndarray, rows: float, lo: float, hi: float, out: np.ndarray) -> bool:
    """:func:`_sample_weights` as one pass over the samples (compiled: the array form allocated five
    temporaries a frame, 19 µs on a 16 × 128 frame); the same operations in the same order, the same
    numbers bit for bit (a NaN sample stays NaN, as ``np.maximum`` keeps it)."""
    check = lo < hi
    outside = 0
    for p in range(y.size):  # branch-free (selects), so that the compiler vectorises it
        signal = y[p] - dark_gray
        signal = 0.0 if signal < 0.0 else signal
        variance = fixed_var + shot_gain * signal
        variance = floor_var if variance < floor_var else variance
        weight = 1.0 / variance * pixel_weight[p] * rows
        inside = (y[p] > lo) & (y[p] < hi)
        outside += not inside
        out[p] = weight * (1.0 if inside or not check else 0.0)
    return not check or outside == 0


def python_twin(function: types.FunctionType, **names) -> types.FunctionType:
    """``function`` run as Python with some of the names it calls bound otherwise (``names``): the
    same control logic, on numpy primitives instead of compiled loops."""
    bound = dict(function.__globals__)
    bound.update(names)
    return types.FunctionType(function.__code__, bound, function.__name__, function.__defaults__,
                              function.__closure__)


def _python_twin(function: types.FunctionType) -> types.FunctionType:
    """``function`` run as Python, its primitives (and the control functions it calls) bound to
    their numpy forms: the fallback, the same control logic with numpy's arithmetic underneath."""
    names = dict(_model_at=_numpy_model_at, _moments_of=_numpy_moments_of, _scalars_of=_numpy_scalars_of,
                 _blob_samples=_numpy_blob_samples, _sizes=_numpy_sizes, _upper_median=_numpy_upper_median,
                 _normalise_and_cut=_numpy_normalise_and_cut, _settle_classes=_numpy_settle_classes,
                 _robust_weights=_numpy_robust_weights, _may_be_blob=_numpy_may_be_blob,
                 _row_moments=_numpy_row_moments)
    if "_gauss_newton" in _PY:
        names["_gauss_newton"] = _PY["_gauss_newton"]
    return python_twin(function, **names)


_PY: dict[str, types.FunctionType] = {}
_PY["_gauss_newton"] = _python_twin(_gauss_newton)
for _name in ("_solve_into", "_robust", "_sample_weights", "_rows_solve_into"):
    _PY[_name] = _python_twin(globals()[_name])

if kernels.numba is not None:  # compiled where numba is (GRAYTRACK_KERNEL=numpy chooses the twin at call time)
    _jit = kernels.numba.njit(cache=True, nogil=True, error_model="numpy")
    # the four sums may be reassociated (vectorised), as the kernel's moments: the same to rounding
    _compiled_scalars_of = kernels.numba.njit(cache=True, nogil=True, error_model="numpy",
                                              fastmath={"reassoc"})(_scalars_of)
    _scalars_of = _compiled_scalars_of
    _blob_samples = _jit(_blob_samples)
    _model_at = _jit(_model_at)
    _moments_of = _jit(_moments_of)
    _light_step = _jit(light_step)
    _middle = _jit(_middle)
    _sizes = _jit(_sizes)
    _upper_median = _jit(_upper_median)
    _normalise_and_cut = _jit(_normalise_and_cut)
    _settle_classes = _jit(_settle_classes)
    _robust_weights = _jit(_robust_weights)
    _may_be_blob = _jit(_may_be_blob)
    _mark_transient = _jit(_mark_transient)
    _fit_figures = _jit(_fit_figures)
    _gauss_newton = _jit(_gauss_newton)
    _row_moments = _jit(_row_moments)
    _rows_solve_into = _jit(_rows_solve_into)
    _solve_into = _jit(_solve_into)
    _robust = _jit(_robust)
    _sample_weights = _jit(_sample_weights_loop)


# --------------------------------------------------------------------------- the calls the solvers make
class _Work:
    """Buffers of one evaluator's solves (kept on it: a frame's solve allocates next to nothing)."""

    __slots__ = ("scratch", "moments", "scalars", "out", "no_mask")

    def __init__(self, n_values: int):
        self.scratch = np.empty((3, n_values))
        self.moments = np.empty(7)
        self.scalars = np.empty(4)
        self.out = np.empty(N_FIELDS)
        self.no_mask = np.zeros(n_values, dtype=np.bool_)


def _setup(evaluator, n_values: int) -> tuple[bool, tuple, np.ndarray, float, "_Work"]:
    """(compiled, model, scratch, the position the scratch holds, buffers) for ``evaluator``."""
    work = getattr(evaluator, "_frame_work", None)
    if work is None or work.scratch.shape[1] != n_values:
        work = _Work(n_values)
        try:
            evaluator._frame_work = work
        except AttributeError:  # an evaluator that takes no attributes: buffers per call
            pass
    if kernels.COMPILED and isinstance(evaluator, kernels.TableEvaluator):
        return True, evaluator._args, evaluator._scratch, evaluator._at, work
    return False, (evaluator,), work.scratch, math.nan, work


def _contiguous(array: np.ndarray) -> np.ndarray:
    return array if array.flags.c_contiguous and array.dtype == np.float64 else \
        np.ascontiguousarray(array, dtype=np.float64)


def solve(evaluator, y: np.ndarray, w: np.ndarray, x: float, free: bool, max_iterations: int, tolerance: float,
          max_step: float) -> np.ndarray:
    """Gauss–Newton on frame ``y`` under weights ``w`` (both ``(P,)``): the :data:`FIELDS` row."""
    y, w = _contiguous(y), _contiguous(w)
    compiled, model, scratch, at, work = _setup(evaluator, y.size)
    function = _solve_into if compiled else _PY["_solve_into"]
    function(y, w, float(x), bool(free), int(max_iterations), float(tolerance), float(max_step), model, scratch, at,
             work.moments, work.scalars, work.out)
    if compiled:
        evaluator._at = work.out[13]
    return work.out


def solve_rows(rows: np.ndarray, orders: np.ndarray, scalars: list[float], x: float, free: bool,
               max_iterations: int, tolerance: float, max_step: float) -> np.ndarray:
    """Gauss–Newton on a frame's moment rows ``(7, D+1)`` (complex) and its four scalars: the
    :data:`FIELDS` row (a new array)."""
    out = np.empty(N_FIELDS)
    function = _rows_solve_into if kernels.COMPILED and kernels.numba is not None else _PY["_rows_solve_into"]
    function(rows, orders, float(scalars[0]), float(scalars[1]), float(scalars[2]), float(scalars[3]), float(x),
             bool(free), int(max_iterations), float(tolerance), float(max_step), np.empty(7), out)
    return out


def robust(evaluator, y: np.ndarray, w: np.ndarray, x: float, gain: float, offset: float, free: bool,
           start_mask: np.ndarray | None, chi2_limit: float, layout: tuple[int, int] | None, max_iterations: int,
           tolerance: float, max_step: float) -> tuple[np.ndarray, np.ndarray]:
    """The robust solve of frame ``y`` (see :func:`_robust`): the :data:`FIELDS` row and the mask of
    the samples set aside (a new array)."""
    y, w = _contiguous(y), _contiguous(w)
    compiled, model, scratch, at, work = _setup(evaluator, y.size)
    mask = np.empty(y.size, dtype=np.bool_)
    use_start = start_mask is not None
    start = work.no_mask if start_mask is None else np.ascontiguousarray(start_mask, dtype=np.bool_).reshape(-1)
    rows, cols = (1, 0) if layout is None else (int(layout[0]), int(layout[1]))
    function = _robust if compiled else _PY["_robust"]
    function(y, w, float(x), float(gain), float(offset), bool(free), start, use_start, float(chi2_limit), rows, cols,
             int(max_iterations), float(tolerance), float(max_step), model, scratch, at, work.moments, work.scalars,
             work.out, mask)
    if compiled:
        evaluator._at = work.out[13]
    return work.out, mask


def sample_weights(y: np.ndarray, noise, pixel_weight: np.ndarray, rows: float,
                   limits: tuple[float, float] | None) -> tuple[np.ndarray, bool]:
    """:func:`_sample_weights` of ``y`` ``(K, P)`` (``pixel_weight`` ``(P,)``): the weights ``(K, P)`` and
    whether no sample sits at the sensor's limits."""
    y = _contiguous(y)
    out = np.empty(y.shape)
    function = _sample_weights if kernels.COMPILED and kernels.numba is not None else _PY["_sample_weights"]
    lo, hi = limits if limits is not None else (math.nan, math.nan)
    flat = y.reshape(-1)
    tiled = pixel_weight if flat.size == pixel_weight.size else np.tile(pixel_weight, y.shape[0])
    shared = function(flat, noise.read_var + noise.quant_var, noise.shot_gain, noise.dark_gray, _MIN_VARIANCE,
                      _contiguous(tiled), float(rows), float(lo), float(hi), out.reshape(-1))
    return out, shared


def warm(evaluator) -> None:
    """Compile (or load from the disk cache) the solves for this evaluator's tables now, at model
    install, not on a live frame."""
    if kernels.COMPILED and kernels.numba is not None:  # the trig path's solve, whatever the evaluator
        solve_rows(np.zeros((7, 2), dtype=complex), 1j * np.arange(2.0), [0.0, 0.0, 1.0, 1.0], 0.0, True, 1, 1.0, 1.0)
    if not (kernels.COMPILED and isinstance(evaluator, kernels.TableEvaluator)):
        return
    n_values = evaluator.tables.n_values
    y, w = np.zeros(n_values), np.ones(n_values)
    solve(evaluator, y, w, 0.0, True, 1, 1.0, 1.0)
    for start in (None, np.zeros(n_values, dtype=bool)):
        robust(evaluator, y, w, 0.0, 1.0, 0.0, True, start, 1.0, (1, n_values), 1, 1.0, 1.0)
    _sample_weights(y, 1.0, 0.0, 0.0, 1.0, w, 1.0, math.nan, math.nan, np.empty(n_values))
    small_linalg.warm()
    evaluator._at = math.nan
