"""A frame solved with a change of focus as a nuisance, on the fast path's moments.

A Gaussian blur of variance δ on the target multiplies harmonic m of the profile by
exp(−2π² δ (m/τ)²). A model whose coefficients do not depend on x sees the target only through
x + s_p, so to first order in δ the blur adds δ·B(x) with

    B = ∂F/∂δ = −2π²/τ² Σ m² (a_m cos mφ + b_m sin mφ) = ½ ∂²F/∂x²

(the heat equation: blurring is diffusion along the target coordinate). B is a trig polynomial
like F, so every inner product the solve needs is a derivative of a moment the fast path already
has (F·F, F′·F′, F·1, y·F), except F″·F″: one more model-level table, built on first use.

The frame model is y ≈ g·F(x) + h·B(x) + o, linear in (g, h, o) at fixed x: they are profiled
out at each Gauss–Newton step in x, the information on x is the Schur complement with the three
of them, and the focus change is δ = h/g. The x Jacobian g·F′ + h·B′ drops the h²·B′·B′ term of
its norm (relative size (2π²δ(M/τ)²)², far below the noise for a blur change of a few pixels).
Valid while 2π²δ(M/τ)² ≪ 1: a change of focus that wipes out the top harmonic is a new model.
Models the fast path cannot hold (stroke terms, a target map) get the same solve with F″ and F‴
from differences of the model's slopes (:func:`general_focus_solve`).

A focus drifts slowly (seconds to minutes), so the last frames' estimates can hold this frame's:
given a :class:`FocusPrior` the blur coefficient gets one more observation in the normal
equations, and the bound on x (the Schur complement given the prior) comes back towards the
uniform light's instead of paying for the blur anew in every frame. The δ each frame reports is
still its own, without the prior: independent estimates for the watch and for the next prior.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from graytrack.core import frame_kernel, kernels, small_linalg
from graytrack.core.evaluation import TrigTables, _trig_coefficients
from graytrack.core.solvers import FrameSolution, SolverSettings, TrigPolyBatch

FOCUS_UNKNOWNS = 3  # gain, blur and offset: what the frame's χ² loses degrees of freedom to
FOCUS_STEP_PERIODS = 1e-3  # finite-difference step of the general path's F″, F‴, in periods


class CurvatureTable:
    """Per pixel, F″² as a trig polynomial of degree 2M (the one moment of the blur term that is
    not a derivative of the fast path's moments), and its weighted sum for the last weights seen."""

    def __init__(self, tables: TrigTables, period_mm: float):
        fast = tables.fast
        harmonics = fast.harmonics
        omega = 2.0 * math.pi / period_mm
        n_samples = 2 * tables.degree + 4
        x = np.arange(n_samples) * period_mm / n_samples
        z = np.exp(1j * omega * np.outer(x, harmonics))
        curvature = (z @ (fast.v * (-(omega * harmonics) ** 2)[:, None])).real  # (N, P)
        self.table = _trig_coefficients(curvature**2, tables.degree)  # (P, D+1)
        self._last: tuple[np.ndarray, np.ndarray, int, bytes, np.ndarray | None] | None = None

    def weighted(self, weights: np.ndarray) -> np.ndarray:
        """Σ_p w_p·F″_p² coefficients ``(D+1,)``; weights every frame shares are folded in once."""
        last = self._last
        # a batch hands each frame a new view of the weights its frames share: the same memory holding
        # the same values folds to the same numbers (compared as bytes: ~1 µs, the product ~10)
        if last is not None and (last[0] is weights or (self._same_memory(last, weights)
                                                        and last[3] == weights.tobytes())):
            return last[1]
        folded = weights @ self.table
        self._last = (weights, folded, weights.ctypes.data, weights.tobytes(), _whole_of(weights))
        return folded

    @staticmethod
    def _same_memory(last: tuple, weights: np.ndarray) -> bool:
        """Whether ``weights`` sit where the last weights sat: both the whole of one buffer (which never
        moves: ~0.1 µs), else by address (numpy's ``ctypes``: ~1 µs)."""
        whole = last[4]
        if whole is not None and whole is _whole_of(weights):
            return True
        return last[2] == weights.ctypes.data


def _whole_of(weights: np.ndarray) -> np.ndarray | None:
    """The buffer ``weights`` are a contiguous view of all of (a batch's ``(1, P)`` shared weights), else None."""
    base = weights.base
    if isinstance(base, np.ndarray) and base.size == weights.size and weights.strides == (weights.itemsize,):
        return base
    return None


def focus_moments(source: TrigPolyBatch, k: int, curvature: CurvatureTable,
                  rejected: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Frame ``k``'s inner products of the blur solve (pixels ``rejected`` set aside): the fast path's
    seven moment rows (F·F, F′·F′, F·1 and y·F are the ones read), the curvature table's F″·F″ row
    (the one product that is not a derivative of those) and the frame's scalars (Σwy², Σwy, Σw, the
    samples used)."""
    weights = source.weights(k)
    if rejected is not None and rejected.any():
        weights = weights * ~rejected
        source, k = source.reweighted(k, weights), 0
    return source.rows[k], curvature.weighted(weights), source.scalars(k)


def _focus_rows(rows: np.ndarray, cc_row: np.ndarray, orders: np.ndarray, x: float, m: np.ndarray) -> None:
    """The seventeen moments at ``x`` into ``m``, each Re Σ_j row_j·e^{P_j x}, the rows derived from
    the base ones (F·F, F′·F′, F·1, y·F of the seven ``rows``; F″·F″, ``cc_row``) with P = iωm (a
    derivative) and the identities F·F″ = ½(F·F)″ − F′·F′, F′·F″ = ½(F′·F′)′: FF, FF″, F″F″, F1,
    F″1, yF, yF″ (the normal equations of g, h, o) and FF′, FF‴, F″F′, F″F‴, F′1, F‴1, F′F′, F′F‴,
    yF′, yF‴ (those of the x Jacobian)."""
    for k in range(17):
        m[k] = 0.0
    for j in range(orders.size):
        p = orders[j]
        z = np.exp(p * x)
        p2 = p * p
        p3 = p2 * p
        ff, dd, f1, yf, cc = rows[0, j] * z, rows[2, j] * z, rows[3, j] * z, rows[5, j] * z, cc_row[j] * z
        fc = 0.5 * p2 * ff - dd  # F·F″
        dc = 0.5 * p * dd  # F′·F″
        m[0] += ff.real
        m[1] += fc.real
        m[2] += cc.real
        m[3] += f1.real
        m[4] += (p2 * f1).real
        m[5] += yf.real
        m[6] += (p2 * yf).real
        m[7] += (0.5 * p * ff).real
        m[8] += (p * fc - dc).real
        m[9] += dc.real
        m[10] += (0.5 * p * cc).real
        m[11] += (p * f1).real
        m[12] += (p3 * f1).real
        m[13] += dd.real
        m[14] += (p * dc - cc).real
        m[15] += (p * yf).real
        m[16] += (p3 * yf).real


def focus_solve(source: TrigPolyBatch, k: int, curvature: CurvatureTable, start: FrameSolution,
                settings: SolverSettings, pixel_pitch_mm: float, prior: FocusPrior | None = None) -> FrameSolution:
    """Gauss–Newton in x from ``start`` with gain, blur and offset profiled out (see the module
    docstring). The solution's ``focus`` is δ in px² of the pixel footprint on the target,
    ``focus_sigma`` its standard error with x, gain and offset estimated too: this frame's own
    estimate, whatever the ``prior`` (see :class:`FocusPrior`) did to x."""
    rows, cc, scalars = focus_moments(source, k, curvature, start.rejected_mask if start.rejected_px else None)
    delta, variance = (prior.delta_mm2, prior.variance_mm4) if prior is not None else (0.0, 0.0)
    has_prior = variance > 0.0
    out = np.empty(_TRIG_OUT)
    compiled = kernels.COMPILED and kernels.numba is not None
    (_trig_focus if compiled else _trig_focus_twin)(
        rows, cc, source.tables.phase_orders, scalars[0], scalars[1], scalars[2], float(start.x_mm),
        float(start.gain), float(start.offset_gray), has_prior, delta if has_prior else 0.0,
        variance if has_prior else 0.0, settings.max_iterations, settings.tolerance_mm,
        settings.max_step_mm, out)
    values = out.tolist()
    return _answer(values[0], values[4:7], values[35:38], values[3], values[2], values[38], scalars[3],
                   int(values[1]), start, settings, pixel_pitch_mm)


# x, iterations, information, cost, θ (3), normal (3×3), projected (3), Fisher (4×4), own θ (3), blur variance
_TRIG_OUT = 39


def _light_and_blur(normal: np.ndarray, projected: np.ndarray, theta: np.ndarray, has_prior: bool,
                    prior_delta: float, prior_variance: float, yy: float, held: np.ndarray,
                    held_projected: np.ndarray) -> float:
    """One focus iteration's (g, h, o): the normal equations with the prior on h = g·δ added (g at
    its last value, ``theta`` on entry), solved into ``theta``; the weighted residual cost there, or
    NaN (``theta`` untouched) when the equations are singular. ``held``, ``held_projected``: work."""
    held[:, :] = normal
    held_projected[:] = projected
    if has_prior:
        variance = theta[0] * theta[0] * prior_variance
        held[1, 1] += 1.0 / variance
        held_projected[1] += theta[0] * prior_delta / variance
    solved = np.empty(3)
    if not _solve3(held, held_projected, solved):
        return math.nan
    theta[:] = solved
    explained = projected[0] * theta[0] + projected[1] * theta[1] + projected[2] * theta[2]
    quadratic = 0.0
    for i in range(3):
        quadratic += (theta[0] * normal[0, i] + theta[1] * normal[1, i] + theta[2] * normal[2, i]) * theta[i]
    return yy - 2.0 * explained + quadratic


def _trig_focus(rows: np.ndarray, cc: np.ndarray, orders: np.ndarray, yy: float, y1: float, ones: float, x: float,
                gain: float, offset: float, has_prior: bool, prior_delta: float, prior_variance: float,
                max_iterations: int, tolerance: float, max_step: float, out: np.ndarray) -> None:
    """The iterations of :func:`focus_solve` on a frame's moment rows (:func:`focus_moments`), into
    ``out`` (see :data:`_TRIG_OUT`): one compiled call instead of some fifteen small numpy ones an iteration."""
    m = np.empty(17)
    theta = np.array([gain, 0.0, offset])
    normal, projected, cross = np.eye(3), np.zeros(3), np.zeros(3)
    held, held_projected, solved = np.empty((3, 3)), np.empty(3), np.empty(3)
    information, cost, jj, iterations = 0.0, math.inf, 0.0, 0
    for iterations in range(1, max_iterations + 1):
        _focus_rows(rows, cc, orders, x, m)
        normal = np.array([[m[0], 0.5 * m[1], m[3]], [0.5 * m[1], 0.25 * m[2], 0.5 * m[4]],
                           [m[3], 0.5 * m[4], ones]])
        projected = np.array([m[5], 0.5 * m[6], y1])
        cost = _light_and_blur(normal, projected, theta, has_prior, prior_delta, prior_variance, yy, held,
                               held_projected)
        if cost != cost:
            break
        g, h = theta[0], 0.5 * theta[1]  # J = g·F′ + h·F‴ (B′ = ½F‴, h·B′ = θ₁·½·F‴)
        cross[0], cross[1], cross[2] = g * m[7] + h * m[8], 0.5 * (g * m[9] + h * m[10]), g * m[11] + h * m[12]
        jj = g * g * m[13] + 2.0 * g * h * m[14]
        numerator = g * m[15] + h * m[16] - (theta[0] * cross[0] + theta[1] * cross[1] + theta[2] * cross[2])
        if not _solve3(held, cross, solved):
            break
        information = jj - (cross[0] * solved[0] + cross[1] * solved[1] + cross[2] * solved[2])
        dx = numerator / information if information > 0.0 else 0.0
        dx = min(max(dx, -max_step), max_step)
        x += dx
        if abs(dx) < tolerance:
            break
    out[0], out[1], out[2], out[3] = x, iterations, information, cost
    out[4:7] = theta
    out[7:16] = normal.reshape(9)
    out[16:19] = projected
    out[19] = jj
    out[20:23] = cross
    for i in range(3):
        out[23 + 4 * i] = cross[i]
        for j in range(3):
            out[24 + 4 * i + j] = normal[i, j]
    # the frame's own (g, h, o) without the prior (the theta solved, when singular), and the blur
    # coefficient's variance from the Fisher matrix of (x, g, h, o) (infinite, when singular)
    own = out[4:7].copy()
    _solve3(out[7:16].reshape(3, 3), out[16:19], own)
    out[35:38] = own
    inverse = np.eye(4)
    out[38] = inverse[2, 2] if _eliminate(out[19:35].reshape(4, 4).copy(), inverse) else math.inf


def general_focus_solve(evaluator, y: np.ndarray, weights: np.ndarray, start: FrameSolution,
                        settings: SolverSettings, period_mm: float, pixel_pitch_mm: float,
                        prior: FocusPrior | None = None) -> FrameSolution:
    """:func:`focus_solve` for models off the trig-polynomial tables (stroke-dependent coefficients,
    a target map, clipping): B = ½F″ and B′ = ½F‴ by central differences of the model's slopes
    (a step of a thousandth of a period: relative error ~(2πM·10⁻³)²/6, far below the noise), the
    same (g, h, o) least squares and Schur complement. Each iteration reads the pixels once, into
    the sums of :func:`_focus_sums`; the rest is algebra on 3×3 matrices. The whole solve is one
    call of :func:`_general_focus` (compiled on a table kernel, its Python twin otherwise)."""
    if start.rejected_px and start.rejected_mask is not None:
        weights = weights * ~start.rejected_mask
    y = np.ascontiguousarray(y, dtype=np.float64)
    weights = np.ascontiguousarray(weights, dtype=np.float64)
    compiled = kernels.COMPILED and isinstance(evaluator, kernels.TableEvaluator)
    model = evaluator._args if compiled else (evaluator,)
    work = np.empty((2, 3, y.size))
    out = np.empty(_FOCUS_OUT)
    delta, variance = (prior.delta_mm2, prior.variance_mm4) if prior is not None else (0.0, 0.0)
    has_prior = variance > 0.0
    (_general_focus if compiled else _general_focus_twin)(
        y, weights, float(start.x_mm), float(start.gain), float(start.offset_gray), FOCUS_STEP_PERIODS * period_mm,
        has_prior, delta if has_prior else 0.0, variance if has_prior else 0.0,
        settings.max_iterations, settings.tolerance_mm, settings.max_step_mm, model, work[0], work[1],
        np.empty(y.size), out)
    x, iterations, information, cost, n_used, blur_variance = out[:6].tolist()
    return _answer(x, out[6:9], out[9:12], cost, information, blur_variance, n_used, int(iterations), start,
                   settings, pixel_pitch_mm)


_FOCUS_OUT = 12  # x, iterations, information, cost, samples used, blur variance, θ (3), own θ (3)


def warm(evaluator, period_mm: float) -> None:
    """Compile (or load from the disk cache) the focus solves now, at model install: the first blurred frame
    must not wait for the compiler (~40 ms from the cache, seconds on a fresh install)."""
    if kernels.COMPILED and kernels.numba is not None:  # the fast path's (trig-polynomial) focus solve
        _trig_focus(np.ones((7, 3), dtype=complex), np.ones(3, dtype=complex), np.ones(3, dtype=complex), 1.0, 1.0,
                    1.0, 0.0, 1.0, 0.0, False, 0.0, 0.0, 1, 1.0, 1.0, np.empty(_TRIG_OUT))
    if not (kernels.COMPILED and isinstance(evaluator, kernels.TableEvaluator)):
        return
    n_values = evaluator.tables.n_values
    settings = SolverSettings(1, 1.0, 1.0, 1.0)
    general_focus_solve(evaluator, np.zeros(n_values), np.ones(n_values), FrameSolution(0.0, 0.0, 0.0, 0),
                        settings, period_mm, 1.0)
    evaluator._at = math.nan


def _model_many(x_mm: np.ndarray, model: tuple, values: np.ndarray, slopes: np.ndarray, smooth: np.ndarray) -> None:
    kernels._evaluate_many(x_mm, *model, values, slopes, smooth)


def _numpy_model_many(x_mm: np.ndarray, model: tuple, values: np.ndarray, slopes: np.ndarray,
                      smooth: np.ndarray) -> None:
    values[:], slopes[:] = model[0].evaluate(x_mm.copy())  # a new array: a model's caches key on its identity


def _numpy_eliminate(a: np.ndarray, b: np.ndarray) -> bool:
    """numpy's solve of ``a x = b`` into ``b`` ``(n, m)``; False when ``a`` is singular."""
    try:
        b[:] = np.linalg.solve(a, b)
    except np.linalg.LinAlgError:
        return False
    return True


def _solve3(a: np.ndarray, b: np.ndarray, x: np.ndarray) -> bool:
    """``x`` = a⁻¹b for a small system, ``a`` and ``b`` left as they were; False when singular."""
    work = a.copy()
    rhs = b.reshape((b.size, 1)).copy()
    if not _eliminate(work, rhs):
        return False
    x[:] = rhs[:, 0]
    return True


def _general_focus(y: np.ndarray, w: np.ndarray, x: float, gain: float, offset: float, step: float,
                   has_prior: bool, prior_delta: float, prior_variance: float, max_iterations: int,
                   tolerance: float, max_step: float, model: tuple, values: np.ndarray, slopes: np.ndarray,
                   smooth: np.ndarray, out: np.ndarray) -> None:
    """The solve of :func:`general_focus_solve` into ``out`` (see :data:`_FOCUS_OUT`)."""
    yy = 0.0
    n_used = 0.0
    for p in range(y.size):
        yy += (y[p] * w[p]) * y[p]
        if w[p] != 0.0:
            n_used += 1.0
    theta = np.array([gain, 0.0, offset])
    information, cost, iterations = 0.0, math.inf, 0
    normal, projected, fisher = np.eye(3), np.zeros(3), np.eye(4)
    sums = np.empty(_FOCUS_SUMS)
    positions = np.empty(3)
    held, held_projected = np.empty((3, 3)), np.empty(3)
    solved, cross = np.empty(3), np.empty(3)
    for iterations in range(1, max_iterations + 1):
        positions[0], positions[1], positions[2] = x - step, x, x + step
        _model_many(positions, model, values, slopes, smooth)
        _focus_sums_of(values, slopes, y, w, step, sums)
        ff, fb, f1, bb, b1, n1, fy, by, y1, fs, bs, s1, ft, bt, t1, sy, ty, ss, st, tt = (
            sums[0], sums[1], sums[2], sums[3], sums[4], sums[5], sums[6], sums[7], sums[8], sums[9], sums[10],
            sums[11], sums[12], sums[13], sums[14], sums[15], sums[16], sums[17], sums[18], sums[19])
        normal = np.array([[ff, fb, f1], [fb, bb, b1], [f1, b1, n1]])
        projected = np.array([fy, by, y1])
        cost = _light_and_blur(normal, projected, theta, has_prior, prior_delta, prior_variance, yy, held,
                               held_projected)
        if cost != cost:
            break
        # the Jacobian in x is J = g·F′ + h·B′: its products with the design, y and itself are linear
        # (quadratic) in the sums, so the step is the profiled one of solvers.profiled_step
        g, h = theta[0], theta[1]
        cross[0], cross[1], cross[2] = g * fs + h * ft, g * bs + h * bt, g * s1 + h * t1
        numerator = g * sy + h * ty - (cross[0] * theta[0] + cross[1] * theta[1] + cross[2] * theta[2])
        slope_norm = g * g * ss + 2.0 * g * h * st + h * h * tt
        if not _solve3(held, cross, solved):
            break
        information = slope_norm - (cross[0] * solved[0] + cross[1] * solved[1] + cross[2] * solved[2])
        fisher = np.empty((4, 4))
        fisher[0, 0] = slope_norm
        fisher[0, 1:] = cross
        fisher[1:, 0] = cross
        fisher[1:, 1:] = normal
        dx = numerator / information if information > 0.0 else 0.0
        dx = min(max(dx, -max_step), max_step)
        x += dx
        if abs(dx) < tolerance:
            break
    own = theta.copy()  # the frame's own (g, h, o) at the final x, without the prior
    _solve3(normal, projected, own)
    inverse = np.eye(4)
    blur_variance = math.inf
    if _eliminate(fisher.copy(), inverse):
        blur_variance = inverse[2, 2]
    out[0], out[1], out[2], out[3], out[4], out[5] = x, iterations, information, cost, n_used, blur_variance
    out[6:9] = theta
    out[9:12] = own


_FOCUS_SUMS = 20


def _focus_sums(values: np.ndarray, slopes: np.ndarray, y: np.ndarray, w: np.ndarray, step: float,
                out: np.ndarray) -> None:
    """One pass over the pixels: with F = values[1], B = ½F″, S = F′ = slopes[1], T = ½F‴ and the
    design (F, B, 1), the weighted sums (into ``out``) FF, FB, F1, BB, B1, 11, Fy, By, 1y,
    FS, BS, 1S, FT, BT, 1T, Sy, Ty, SS, ST, TT."""
    for k in range(out.size):
        out[k] = 0.0
    half_over_step = 0.25 / step
    turn_scale = 0.5 / (step * step)
    for p in range(y.size):
        wp = w[p]
        if wp == 0.0:
            continue
        f = values[1, p]
        b = half_over_step * (slopes[2, p] - slopes[0, p])
        s = slopes[1, p]
        t = turn_scale * (slopes[2, p] - 2.0 * slopes[1, p] + slopes[0, p])
        yp = y[p]
        wf, wb = wp * f, wp * b
        out[0] += wf * f
        out[1] += wf * b
        out[2] += wf
        out[3] += wb * b
        out[4] += wb
        out[5] += wp
        out[6] += wf * yp
        out[7] += wb * yp
        out[8] += wp * yp
        out[9] += wf * s
        out[10] += wb * s
        out[11] += wp * s
        out[12] += wf * t
        out[13] += wb * t
        out[14] += wp * t
        out[15] += wp * s * yp
        out[16] += wp * t * yp
        out[17] += wp * s * s
        out[18] += wp * s * t
        out[19] += wp * t * t


def _focus_sums_numpy(values: np.ndarray, slopes: np.ndarray, y: np.ndarray, w: np.ndarray, step: float,
                      out: np.ndarray) -> None:
    """:func:`_focus_sums` by numpy products (where numba is missing: a Python loop over pixels is not)."""
    f, s = values[1], slopes[1]
    b = (0.25 / step) * (slopes[2] - slopes[0])
    t = (0.5 / (step * step)) * (slopes[2] - 2.0 * slopes[1] + slopes[0])
    columns = np.stack([f, b, np.ones_like(f)])
    weighted = columns * w
    normal = weighted @ columns.T
    out[:] = [normal[0, 0], normal[0, 1], normal[0, 2], normal[1, 1], normal[1, 2], normal[2, 2],
              *(weighted @ y), *(weighted @ s), *(weighted @ t),
              (w * s) @ y, (w * t) @ y, (w * s) @ s, (w * s) @ t, (w * t) @ t]


_compiled_focus_sums = kernels.numba.njit(cache=True, nogil=True)(_focus_sums) if kernels.numba is not None else None


@dataclass(frozen=True)
class FocusPrior:
    """What the last frames say about the focus (δ in mm² and its variance): a focus drifts slowly,
    so a frame need not find it again on its own. It enters the frame's normal equations as one
    more observation of the blur coefficient; the information on x is then the Schur complement
    given it, close to the uniform light's once the prior is much tighter than one frame."""

    delta_mm2: float
    variance_mm4: float


def _answer(x: float, theta: Sequence[float], own: Sequence[float], cost: float, information: float,
            blur_variance: float, n_used: float, iterations: int, start: FrameSolution, settings: SolverSettings,
            pixel_pitch_mm: float) -> FrameSolution:
    """The frame's answer with the focus term: x, gain and offset as solved (``theta``); δ = h/g in
    px² and its standard error from the frame's own estimate (``own``, without the prior) and the
    blur coefficient's variance (the Fisher matrix of (x, g, h, o) inverted)."""
    chi2 = max(cost, 0.0) / max(n_used - FOCUS_UNKNOWNS - 1, 1.0)
    gain, offset = float(theta[0]), float(theta[2])
    own_gain, blur = float(own[0]), float(own[1])
    footprint = pixel_pitch_mm * pixel_pitch_mm
    focus = blur / own_gain / footprint if own_gain else float("nan")
    focus_sigma = math.sqrt(max(blur_variance, 0.0)) / abs(own_gain) / footprint if own_gain else float("nan")
    return FrameSolution(x, settings.sigma_gray * math.sqrt(chi2), information, iterations, gain, offset, chi2,
                         start.rejected_px, True, 0.0, cost, start.rejected_mask, start.rejected_weights_exact,
                         focus=focus, focus_sigma=focus_sigma, focus_solved=True)


_eliminate = small_linalg._eliminate  # compiled where numba is
_focus_sums_of = _compiled_focus_sums if _compiled_focus_sums is not None else _focus_sums_numpy
_solve3_twin = frame_kernel.python_twin(_solve3, _eliminate=_numpy_eliminate)
_light_and_blur_twin = frame_kernel.python_twin(_light_and_blur, _solve3=_solve3_twin)
_general_focus_twin = frame_kernel.python_twin(_general_focus, _model_many=_numpy_model_many,
                                               _focus_sums_of=_focus_sums_numpy, _eliminate=_numpy_eliminate,
                                               _solve3=_solve3_twin, _light_and_blur=_light_and_blur_twin)
_trig_focus_twin = frame_kernel.python_twin(_trig_focus, _solve3=_solve3_twin, _light_and_blur=_light_and_blur_twin,
                                            _eliminate=_numpy_eliminate)
if kernels.numba is not None:
    _jit = kernels.numba.njit(cache=True, nogil=True, error_model="numpy")
    _model_many = _jit(_model_many)
    _solve3 = _jit(_solve3)
    _light_and_blur = _jit(_light_and_blur)
    _general_focus = _jit(_general_focus)
    _focus_rows = _jit(_focus_rows)
    _trig_focus = _jit(_trig_focus)
