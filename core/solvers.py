"""Per-frame position solvers: weighted Gauss–Newton for x, with the light's gain and offset as
optional nuisance parameters, and a robust reweighting for pixels that went bad in the run.

The frame model is y ≈ g·F(x) + o with weights w = 1/σ² per pixel. Everything one Gauss–Newton
step needs is a handful of weighted inner products at the trial x (the *moments*):

    F·F, F′·F, F′·F′, F·1, F′·1, y·F, y·F′        (x-dependent)
    y·y, y·1, 1·1                                 (per frame)

Two sources of moments share one solver: :class:`TrigPolyBatch` (the fast path), where each
x-dependent moment is a trigonometric polynomial in x whose coefficients are matrix products of
the frame and its weights with model-level tables, so the per-frame work is a few scalar
evaluations; and :class:`GeneralBatch`, which evaluates the model at x (stroke-dependent
coefficients, clipping, a target map). The step, the gain/offset profile, the Schur-complement
information, the grid cost for acquisition and the robust loop are written once, here.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from graytrack.core import frame_kernel, small_linalg
from graytrack.core.evaluation import ClippedHarmonics, FastHarmonics, GeneralHarmonics, TrigTables
# the robust solve's constants live with its control logic (core/frame_kernel.py)
from graytrack.core.frame_kernel import (CORE_SIGMA, CUT_SIGMA, MAD_TO_SIGMA, ROBUST_ITERATIONS,  # noqa: F401
                                         TRANSIENT_MAX_WIDTH_SHARE)

MASK_CACHE_SIZE = 64  # masks of rejected pixels whose moment tables are kept (one bad pixel: one mask)
SET_ASIDE_BLOCK = 64  # frames whose moments lose a set-aside pixel's share in one vectorised step


@dataclass
class FrameSolution:
    """One frame's solve. ``rms_gray`` is √χ² × the model's σ (the residual rms were every pixel of that σ);
    a field named in core/frame_record.py is the quantity declared there (``rejected_px``: the samples the
    robust reweighting gave zero weight)."""

    x_mm: float
    rms_gray: float
    information: float  # Fisher information on x (1/mm²), gain/offset profiled out when solved
    iterations: int
    gain: float = 1.0
    offset_gray: float = 0.0
    chi2: float = float("nan")
    rejected_px: int = 0
    free_light: bool = False  # gain and offset were solved with x
    light_excess: float = 0.0  # χ² added by forcing the calibrated light (gain 1, offset 0) at this x
    cost: float = float("nan")  # weighted residual Σ w·r² (χ² before dividing by the degrees of freedom)
    rejected_mask: np.ndarray | None = None  # which pixels were rejected (for the next frame's start)
    rejected_weights_exact: bool = True  # the solve used 0/1 weights: a repeat with the same set adds nothing
    field: bool = False  # a light field (gain smooth across the pixels) was solved with x
    shape: np.ndarray | None = None  # the field's shape: gain coefficients beyond the uniform one
    shape_precision: np.ndarray | None = None  # their inverse covariance, x and the rest profiled out
    transient_px: int = 0
    transient_share: float = 0.0  # those as a share of the frame's samples (raw rows when set aside row by row)
    transient_at: float = float("nan")  # mean pixel (column) of those samples: where along the line they sit
    focus: float = 0.0  # change of blur variance since calibration (px² of the pixel footprint), when estimated
    focus_sigma: float = float("nan")  # its standard error (NaN: the focus was not estimated on this frame)
    focus_solved: bool = False  # the answer has the focus term profiled out (its bound is the Schur complement)
    chi2_calibrated_focus: float = float("nan")  # with focus_solved: the frame's χ² at the calibration's focus
    moving: bool = False  # a light feature moving across the field was followed with x (core/moving_band.py)
    period_guess: bool = False  # acquired without a grating, another period still fits as well (core/period_rival.py)
    pulled: bool = False  # the print's learned marks moved it from where the print alone places it (core/texture.py)


class MomentSource(Protocol):
    """What the solver needs from a batch of reduced frames (the robust solve evaluates the model
    pixel by pixel on ``evaluator``, over ``frames``)."""

    n_frames: int
    frames: np.ndarray
    evaluator: Any

    def moments(self, k: int, x_mm: float) -> list[float]: ...
    def grid_moments(self, k: int, grid: np.ndarray) -> np.ndarray: ...
    def scalars(self, k: int) -> list[float]: ...
    def residuals(self, k: int, x_mm: float, gain: float, offset: float,
                  pixels: np.ndarray | None = None) -> np.ndarray: ...
    def weights(self, k: int) -> np.ndarray: ...
    def reweighted(self, k: int, weights: np.ndarray) -> "MomentSource": ...
    def without(self, k: int, rejected: np.ndarray) -> "MomentSource | FrameMoments": ...
    def set_aside_residuals(self, k: int, x_mm: float, gain: float, offset: float,
                            rejected: np.ndarray) -> list[float]: ...


class RowMoments(Protocol):
    """What the moment-row Gauss–Newton reads of a frame: the fast path's batch, or one frame's
    moments with its samples set aside (:class:`FrameMoments`)."""

    def scalars(self, k: int) -> list[float]: ...
    def moment_rows(self, k: int) -> tuple[np.ndarray, np.ndarray]: ...


# --------------------------------------------------------------------------- the shared solver
@dataclass(frozen=True)
class SolverSettings:
    max_iterations: int
    tolerance_mm: float
    max_step_mm: float
    sigma_gray: float  # the model's σ, to report χ² as an equivalent rms in gray


def gauss_newton(source: "GeneralBatch | RowMoments", k: int, x_start: float, free: bool,
                 settings: SolverSettings) -> FrameSolution:
    """Weighted Gauss–Newton on frame ``k`` from ``x_start``; gain/offset profiled when ``free``.
    A source that evaluates its model pixel by pixel (:class:`GeneralBatch`) is solved in one call
    of core/frame_kernel.py on its pixels; a source of moment tables (the trig-polynomial fast
    path) in one call on its frame's moment rows."""
    if isinstance(source, GeneralBatch):
        return _solution(frame_kernel.solve(source.evaluator, source.frames[k], source.weights(k), x_start, free,
                                            settings.max_iterations, settings.tolerance_mm, settings.max_step_mm),
                         free, settings)
    rows, orders = source.moment_rows(k)
    return _solution(frame_kernel.solve_rows(rows, orders, source.scalars(k), x_start, free, settings.max_iterations,
                                             settings.tolerance_mm, settings.max_step_mm), free, settings)


def grid_cost(source: MomentSource, k: int, grid: np.ndarray, free: bool) -> np.ndarray:
    """Weighted residual cost at each grid position; with ``free`` light it is the cost after the
    best gain and offset at that position (invariant to the light), and a non-positive gain is
    refused (it would fit the target's negative)."""
    m = source.grid_moments(k, grid)  # (G, 7)
    yy, y1, s11 = source.scalars(k)[:3]
    ff, f1, yf = m[:, 0], m[:, 3], m[:, 5]
    if not free:
        return yy - 2.0 * yf + ff
    det = np.maximum(ff * s11 - f1 * f1, 1e-300)
    gain = (yf * s11 - f1 * y1) / det
    explained = (yf * yf * s11 - 2.0 * yf * y1 * f1 + y1 * y1 * ff) / det
    return yy - explained + np.where(gain > 0.0, 0.0, np.inf)


def robust_solve(source: MomentSource, k: int, start: FrameSolution, free: bool, settings: SolverSettings,
                 rejected: np.ndarray | None = None, chi2_limit: float = -1.0,
                 layout: tuple[int, int] | None = None) -> FrameSolution:
    """Iteratively reweighted least squares with a redescending weight on the normalised residuals.

    Starts from ``start`` (a position and light close to the truth, e.g. the motion prediction)
    and, when given, the pixels the previous frame rejected (when the others then fit, χ² within
    ``chi2_limit``, and those are still beyond the cut, that is the answer: a bad pixel that stays
    bad costs one solve per frame); scales the residuals by their median
    absolute value (never below the noise model), weighs them by a redescending weight (1 inside
    ``CORE_SIGMA``, Tukey's biweight taper to 0 at ``CUT_SIGMA``) and solves
    again, until the set of rejected pixels settles. The bound comes with the weights used: that
    of the pixels kept. When no pixel sits in the taper (the usual case) the weights are a mask.

    With ``layout`` (rows, pixels of a frame), an outlier that is part of a compact blob (a glint,
    passing dust: core/transients.py) takes its whole support with it, tails down to
    ``transients.GROW_Z`` and a pixel beyond: the tails of a glint bright enough to reject sit
    below the cut and would otherwise pull the position (``transient_px`` counts those samples).

    The whole solve is one call of core/frame_kernel.py on the source's model evaluator (compiled
    on a table kernel, its Python twin otherwise).
    """
    out, mask = frame_kernel.robust(source.evaluator, source.frames[k], source.weights(k), start.x_mm, start.gain,
                                    start.offset_gray, free, rejected, chi2_limit, layout, settings.max_iterations,
                                    settings.tolerance_mm, settings.max_step_mm)
    return _solution(out, free, settings, mask)


def _solution(out: np.ndarray, free: bool, settings: SolverSettings, mask: np.ndarray | None = None) -> FrameSolution:
    """A solve's row of core/frame_kernel.py FIELDS as a :class:`FrameSolution`."""
    (x, iterations, information, gain, offset, cost, chi2, excess, rejected, exact, transient_px, transient_share,
     transient_at, _, masked) = out.tolist()
    solution = FrameSolution(x, settings.sigma_gray * math.sqrt(chi2), information, int(iterations), gain, offset,
                             chi2, int(rejected), free, excess, cost=cost)
    if masked:
        solution.rejected_mask, solution.rejected_weights_exact = mask, bool(exact)
        solution.transient_px, solution.transient_share, solution.transient_at = \
            int(transient_px), transient_share, transient_at
    return solution


def _set_aside_residuals(source: MomentSource, k: int, x_mm: float, gain: float, offset: float,
                         rejected: np.ndarray) -> list[float]:
    """|residual|·√w of the ``rejected`` pixels, from any source."""
    pixels = np.flatnonzero(rejected)
    return (np.abs(source.residuals(k, x_mm, gain, offset, pixels)) * np.sqrt(source.weights(k)[pixels])).tolist()


# --------------------------------------------------------------------------- moment sources
@dataclass(frozen=True)
class StaticWeights:
    """Weights every frame shares (constant noise, masked pixels): their part of the moments, once."""

    weights: np.ndarray  # (1, P)
    gram: np.ndarray  # (1, 5, 2M+1): F·F, F′·F, F′·F′, F·1, F′·1 under these weights
    total: float
    count: int
    masked: dict[bytes, "SetAside"] = field(default_factory=dict)  # the same with pixels set aside
    last_set_aside: list = field(default_factory=list)  # [mask, SetAside]: the set the last frame used

    @classmethod
    def of(cls, tables: TrigTables, weights: np.ndarray) -> "StaticWeights":
        return cls(weights, tables.weighted_gram(weights), float(weights.sum()), int((weights > 0).sum()))

    def set_aside(self, tables: TrigTables, rejected: np.ndarray) -> "SetAside":
        """What the fast path keeps for the pixels ``rejected`` (a mask): built once per set, and
        found again without a look-up while the same mask carries from frame to frame."""
        last = self.last_set_aside
        if last and last[0] is rejected:
            return last[1]
        removed = np.flatnonzero(rejected)
        key = removed.tobytes()
        found = self.masked.get(key)
        if found is None:
            if len(self.masked) >= MASK_CACHE_SIZE:
                self.masked.clear()
            found = self.masked[key] = SetAside.of(self, tables, removed)
        last[:] = [rejected, found]
        return found


@dataclass(frozen=True)
class SetAside:
    """Pixels set aside from weights every frame shares: the kept pixels' tables, and the set-aside
    pixels' own share of a frame's moments (subtracted per frame: O(set aside), not O(pixels))
    and of its model values (a set-aside pixel is checked in scalar Python: a few pixels)."""

    removed: np.ndarray  # pixel indices
    kept: StaticWeights  # the weights with these pixels at zero, and their moment tables
    weights: np.ndarray  # (R,) their base weights
    linear: np.ndarray  # (R, M+2) complex: their y·F and y·1 coefficients per unit y (TrigTables.linear)
    roots: list[float]  # √weight, to normalise their residuals
    lines: list[list[complex]]  # F of each as coefficients of z^0..z^M
    omega_i: complex  # iω: z = exp(iω·x)

    @classmethod
    def of(cls, static: StaticWeights, tables: TrigTables, removed: np.ndarray) -> "SetAside":
        keep = np.ones(static.weights.shape[1], dtype=bool)
        keep[removed] = False
        weights = static.weights[0, removed]
        return cls(removed, StaticWeights.of(tables, static.weights * keep), weights,
                   tables.linear[removed].view(complex), np.sqrt(weights).tolist(),
                   tables.line_coefficients(removed), complex(tables.phase_orders[1]))

    def normalised_residuals(self, y: list[float], x_mm: float, gain: float, offset: float) -> list[float]:
        """|y − (g·F(x) + o)|·√w of each set-aside pixel."""
        z = cmath.exp(self.omega_i * x_mm)
        out = []
        for value, line, root in zip(y, self.lines, self.roots):
            model, power = line[0].real, 1.0 + 0j
            for coefficient in line[1:]:
                power *= z
                model += (coefficient * power).real
            out.append(abs(value - gain * model - offset) * root)
        return out


class TrigPolyBatch:
    """The fast path: per frame a (7, 2M+1) matrix of trig-polynomial coefficients, then scalars.

    For a model whose coefficients do not depend on x, each pixel's F_p, F_p², F′_p² are trig
    polynomials with model-level coefficients (:class:`TrigTables`). A weighted moment is then
    Σ_p w_p·(coefficients of pixel p): the weights of every frame fold in by one matrix product,
    exact whether the weights are fixed (noise model, masked pixels) or change per frame
    (signal-dependent variance, robust reweighting). Per iteration: z^0..z^2M and one 7×(2M+1)
    product.
    """

    raw: np.ndarray | None = None  # (K, R, n) the strip rows a row-averaged batch was made of, when kept

    def __init__(self, tables: TrigTables, frames: np.ndarray, weights: np.ndarray,
                 static: StaticWeights | None = None, evaluator=None):
        frames = frames.reshape(frames.shape[0], -1)
        self.tables, self.frames, self.n_frames = tables, frames, frames.shape[0]
        # what the robust solve evaluates the model with, pixel by pixel (the tracker's table kernel)
        self.evaluator = evaluator if evaluator is not None else tables.fast
        self._weights = weights  # (K, P) or (1, P) when every frame shares them
        self._static = static
        self._set_aside_block: SetAsideBlock | None = None  # the last block :meth:`without` built
        width = tables.degree + 1
        weighted = weights * frames
        linear = (weighted @ tables.linear).view(complex)  # y·F coefficients, and y·1
        gram = static.gram if static is not None else tables.weighted_gram(weights)
        self.rows = np.zeros((self.n_frames, 7, width), dtype=complex)  # (K, 7, D+1)
        self.rows[:, :5] = gram
        tables.linear_rows(linear, out=self.rows[:, 5:])
        y_norm = (weighted * frames).sum(axis=1).tolist()
        y_sum = linear[:, -1].real.tolist()
        if static is not None:
            self._scalars = [[a, b, static.total, static.count] for a, b in zip(y_norm, y_sum)]
        else:
            self._scalars = [list(item) for item in zip(y_norm, y_sum, weights.sum(axis=1).tolist(),
                                                         (weights > 0).sum(axis=1).tolist())]

    def reload(self, frame: np.ndarray) -> "TrigPolyBatch":
        """This one-frame batch with weights every frame shares, for the next ``frame`` ``(1, P)``:
        the same reduction written into the buffers it already has (live tracking allocates
        nothing per frame but the small moment lists)."""
        if self.n_frames != 1 or self._static is None:
            raise ValueError("only a one-frame batch with shared weights reloads")
        if not hasattr(self, "_buffers"):
            self._buffers = (np.empty_like(self.frames), np.empty((1, self.tables.linear.shape[1])))
        weighted, linear = self._buffers
        self.frames = frame
        np.multiply(self._weights, frame, out=weighted)
        np.matmul(weighted, self.tables.linear, out=linear)
        coefficients = linear.view(complex)[0]
        self.tables.linear_rows(linear.view(complex), out=self.rows[:, 5:])
        np.multiply(weighted, frame, out=weighted)
        self._scalars = [[float(weighted.sum()), coefficients[-1].real, self._static.total, self._static.count]]
        self._set_aside_block = None
        return self

    def scalars(self, k: int) -> list[float]:
        return self._scalars[k]

    def moments(self, k: int, x_mm: float) -> list[float]:
        return self.rows[k].dot(np.exp(self.tables.phase_orders * x_mm)).real.tolist()

    def moment_rows(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``k``'s moment rows ``(7, D+1)`` and their orders iωj (moments = Re rows·e^{orders·x})."""
        return self.rows[k], self.tables.phase_orders

    def grid_moments(self, k: int, grid: np.ndarray) -> np.ndarray:
        return (np.exp(np.outer(grid, self.tables.phase_orders)) @ self.rows[k].T).real

    def weights(self, k: int) -> np.ndarray:
        return self._weights[k if self._weights.shape[0] > 1 else 0]

    def residuals(self, k: int, x_mm: float, gain: float, offset: float,
                  pixels: np.ndarray | None = None) -> np.ndarray:
        """y − (g·F(x) + o), of every pixel or of ``pixels``."""
        y = self.frames[k] if pixels is None else self.frames[k, pixels]
        return y - gain * self.tables.values_at(x_mm, pixels) - offset

    def reweighted(self, k: int, weights: np.ndarray) -> "TrigPolyBatch":
        return TrigPolyBatch(self.tables, self.frames[k:k + 1], weights[None], evaluator=self.evaluator)

    def without(self, k: int, rejected: np.ndarray) -> "TrigPolyBatch | FrameMoments":
        """Frame ``k`` with the ``rejected`` pixels set aside. With weights every frame shares, the
        kept pixels' tables come from the cache and the frame's own moments lose the rejected
        pixels' share by a subtraction."""
        if self._static is None:
            return self.reweighted(k, self.weights(k) * ~rejected)
        block = self._block(k, rejected)
        j = k - block.start
        return FrameMoments(block.rows[j], block.scalars[j], self.tables.phase_orders)

    def set_aside_residuals(self, k: int, x_mm: float, gain: float, offset: float,
                            rejected: np.ndarray) -> list[float]:
        """|residual|·√w of the ``rejected`` pixels at this solution."""
        if self._static is None:
            return _set_aside_residuals(self, k, x_mm, gain, offset, rejected)
        block = self._block(k, rejected)
        return block.plan.normalised_residuals(block.values[k - block.start], x_mm, gain, offset)

    def _block(self, k: int, rejected: np.ndarray) -> "SetAsideBlock":
        static = self._static
        if static is None:  # (asked only with static weights: set_aside_residuals, without)
            raise ValueError("samples are set aside in blocks only under static weights")
        plan = static.set_aside(self.tables, rejected)
        block = self._set_aside_block
        if block is None or block.plan is not plan or not block.start <= k < block.stop:
            block = self._set_aside_block = self._block_without(plan, k, min(k + SET_ASIDE_BLOCK, self.n_frames))
        return block

    def _block_without(self, plan: "SetAside", start: int, stop: int) -> "SetAsideBlock":
        """Frames ``start:stop`` with ``plan``'s pixels set aside, in one vectorised step: a bad
        pixel usually stays bad for many frames, so its share is subtracted for a block at once."""
        y = self.frames[start:stop, plan.removed]
        wy = y * plan.weights
        share = wy @ plan.linear  # (B, M+2)
        lines = self.tables.linear_rows(share)  # (B, 2, D+1)
        kept = plan.kept
        if stop - start == 1:  # live tracking: one frame, no lists to build
            rows = np.empty((1,) + self.rows.shape[1:], dtype=complex)
            rows[0, :5] = kept.gram[0]
            np.subtract(self.rows[start, 5:], lines[0], out=rows[0, 5:])
            y_norm, y_sum = self._scalars[start][:2]
            scalars = [[y_norm - float(wy[0] @ y[0]), y_sum - share[0, -1].real, kept.total, kept.count]]
            return SetAsideBlock(plan, start, stop, rows, scalars, y.tolist())
        linear = self.rows[start:stop, 5:] - lines
        rows = np.concatenate((np.broadcast_to(kept.gram, (stop - start,) + kept.gram.shape[1:]), linear), axis=1)
        y_norm = [item[0] for item in self._scalars[start:stop]] - (wy * y).sum(axis=1)
        y_sum = [item[1] for item in self._scalars[start:stop]] - share[:, -1].real
        scalars = [[a, b, kept.total, kept.count] for a, b in zip(y_norm.tolist(), y_sum.tolist())]
        return SetAsideBlock(plan, start, stop, rows, scalars, y.tolist())


@dataclass(frozen=True)
class SetAsideBlock:
    """Frames ``start:stop`` of a batch with a set of pixels set aside: their moments, and the
    set-aside pixels' values (to check they are still outliers)."""

    plan: SetAside
    start: int
    stop: int
    rows: np.ndarray  # (B, 7, D+1)
    scalars: list[list[float]]
    values: list[list[float]]  # (B, set aside)


class FrameMoments:
    """One frame's moment coefficients, as much of a source as Gauss–Newton reads (the solve of
    a frame with pixels set aside: a few µs per frame, so nothing else is built)."""

    __slots__ = ("rows", "_scalars", "phase_orders")
    n_frames = 1

    def __init__(self, rows: np.ndarray, scalars: list[float], phase_orders: np.ndarray):
        self.rows, self._scalars, self.phase_orders = rows, scalars, phase_orders

    def scalars(self, k: int) -> list[float]:
        return self._scalars

    def moments(self, k: int, x_mm: float) -> list[float]:
        return self.rows.dot(np.exp(self.phase_orders * x_mm)).real.tolist()

    def moment_rows(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        return self.rows, self.phase_orders


class GeneralBatch:
    """Moments by evaluating the model at x: any model (stroke drift, clipping, a target map)."""

    raw: np.ndarray | None = None  # (K, R, n) the strip rows a row-averaged batch was made of, when kept

    def __init__(self, evaluator: "FastHarmonics | GeneralHarmonics | ClippedHarmonics", frames: np.ndarray,
                 weights: np.ndarray):
        self.frames = frames.reshape(frames.shape[0], -1)
        self.n_frames = self.frames.shape[0]
        self.evaluator = evaluator
        self._weights = weights
        self._scalars: list[list[float]] | None = None  # on first use: the solves reduce their frame themselves

    def reload(self, frame: np.ndarray) -> "GeneralBatch":
        """This one-frame batch with weights every frame shares, for the next ``frame`` ``(1, P)``."""
        if self.n_frames != 1 or self._weights.shape[0] != 1:
            raise ValueError("only a one-frame batch with shared weights reloads")
        np.copyto(self.frames, frame.reshape(self.frames.shape))
        self._scalars = None
        return self

    def scalars(self, k: int) -> list[float]:
        """Σw·y², Σw·y, Σw and the samples used of frame ``k`` (the moment solver's and the grid's)."""
        if self._scalars is None:
            weighted = self._weights * self.frames
            self._scalars = np.stack(np.broadcast_arrays(
                np.einsum("kp,kp->k", weighted, self.frames), weighted.sum(axis=1), self._weights.sum(axis=1),
                (self._weights > 0).sum(axis=1)), axis=1).tolist()
        return self._scalars[k]

    def weights(self, k: int) -> np.ndarray:
        return self._weights[k if self._weights.shape[0] > 1 else 0]

    def grid_moments(self, k: int, grid: np.ndarray) -> np.ndarray:
        values, slopes = self.evaluator.evaluate(np.asarray(grid, dtype=np.float64))
        w, y = self.weights(k), self.frames[k]
        wv, ws = values * w, slopes * w
        return np.stack([(wv * values).sum(1), (ws * values).sum(1), (ws * slopes).sum(1), wv.sum(1), ws.sum(1),
                         wv @ y, ws @ y], axis=1)

    def moments(self, k: int, x_mm: float) -> list[float]:
        kernel = getattr(self.evaluator, "moments", None)  # the compiled kernel of a model's frame tables
        if kernel is not None:
            return kernel(x_mm, self.frames[k], self.weights(k))
        return self.grid_moments(k, np.array([x_mm]))[0].tolist()

    def residuals(self, k: int, x_mm: float, gain: float, offset: float,
                  pixels: np.ndarray | None = None) -> np.ndarray:
        values, _ = self.evaluator.evaluate(np.array([x_mm]))
        residual = self.frames[k] - gain * values[0] - offset
        return residual if pixels is None else residual[pixels]

    def reweighted(self, k: int, weights: np.ndarray) -> "GeneralBatch":
        return GeneralBatch.one(self.evaluator, self.frames[k:k + 1], weights[None])

    @classmethod
    def one(cls, evaluator: "FastHarmonics | GeneralHarmonics | ClippedHarmonics", frame: np.ndarray,
            weights: np.ndarray) -> "GeneralBatch":
        """A batch of one frame ``(1, P)`` under its own weights ``(1, P)`` (a live frame, or a frame
        solved again with samples set aside), built without a reduction: its scalars on first use."""
        batch = cls.__new__(cls)
        batch.frames, batch.n_frames, batch.evaluator, batch._weights = frame, 1, evaluator, weights
        batch._scalars = None
        return batch

    def without(self, k: int, rejected: np.ndarray) -> "GeneralBatch":
        return self.reweighted(k, self.weights(k) * ~rejected)

    def set_aside_residuals(self, k: int, x_mm: float, gain: float, offset: float,
                            rejected: np.ndarray) -> list[float]:
        return _set_aside_residuals(self, k, x_mm, gain, offset, rejected)


# --------------------------------------------------------------------------- a light field
FIELD_DEGREE = 2  # Legendre degree of the gain across the line (the offset stays uniform): 4 nuisances
# Why not the offset's shape too: the line spans less than a period, so a shift of the pattern is
# itself close to a smooth change across the line; a quadratic offset on top of a quadratic gain
# leaves x almost unidentified (paper rig: bound 68 µm against 10 µm with the offset uniform).


def profiled_step(jacobian: np.ndarray, weighted: np.ndarray, weights: np.ndarray, yw: np.ndarray,
                  theta: np.ndarray, held: np.ndarray, normal: np.ndarray,
                  max_step_mm: float) -> tuple[float, float, np.ndarray]:
    """One Gauss–Newton step in x with the linear nuisances (columns of the design, ``weighted`` =
    design × weights, solved as ``theta`` from the normal matrix ``held``, which may carry a prior)
    profiled out: ``(step, information on x, the Fisher matrix of x and the nuisances)``. The
    information is the Schur complement: what the frame says about x once the nuisances took their share."""
    cross = weighted.T @ jacobian
    numerator = float(jacobian @ (yw - weighted @ theta))
    slope_norm = float(jacobian @ (jacobian * weights))
    information = slope_norm - float(cross @ small_linalg.solve(held, cross))
    fisher = np.empty((cross.size + 1, cross.size + 1))
    fisher[0, 0], fisher[0, 1:], fisher[1:, 0], fisher[1:, 1:] = slope_norm, cross, cross, normal
    step = numerator / information if information > 0.0 else 0.0
    return min(max(step, -max_step_mm), max_step_mm), information, fisher


def field_basis(n_rows: int, n_pixels: int, degree: int = FIELD_DEGREE) -> np.ndarray:
    """``(R·n, degree+1)`` Legendre polynomials of the pixel's column scaled to [−1, 1], the same in
    every row: the shapes a light may take across the line (vignetting, a gradient) that a
    uniform gain and offset cannot follow."""
    u = np.tile(np.linspace(-1.0, 1.0, n_pixels), n_rows)
    return np.polynomial.legendre.legvander(u, degree)


def field_solve(evaluator: "FastHarmonics | GeneralHarmonics | ClippedHarmonics", y: np.ndarray,
                weights: np.ndarray, basis: np.ndarray, start: FrameSolution,
                settings: SolverSettings) -> FrameSolution:
    """Gauss–Newton in x with a light *field* profiled out: y ≈ L(p)·F(x) + o, where the gain L is
    smooth across the pixels (``basis`` columns) and the offset o uniform.

    Asked for only when a uniform gain and offset leave χ² above the calibration's level, so it
    evaluates F and F′ at x directly (no tables) and solves a small least squares per step. The
    information on x is the Schur complement with the degree+2 nuisances: the honest, larger floor.
    ``cost`` is the weighted residual, to set against the uniform light's at its own best x;
    ``shape`` and ``shape_precision`` let the caller check that the shape holds still from frame to
    frame, as a light's does (a change of the pattern that the field merely mimics does not)."""
    n_basis = basis.shape[1]
    x = float(start.x_mm)
    yw = y * weights
    yy, n_used = float(yw @ y), float(np.count_nonzero(weights))
    theta = np.zeros(n_basis + 1)  # the gain's Legendre coefficients, then the offset
    theta[0], theta[n_basis] = start.gain, start.offset_gray
    information, cost, iterations = 0.0, float("inf"), 0
    fisher = np.eye(n_basis + 2)
    for iterations in range(1, settings.max_iterations + 1):
        values, slopes = evaluator.evaluate(np.array([x]))
        design = np.concatenate((basis * values[0][:, None], np.ones((y.size, 1))), axis=1)  # (P, B+1)
        weighted = design * weights[:, None]
        normal, projected = weighted.T @ design, weighted.T @ y
        try:
            theta = small_linalg.solve(normal, projected)
        except np.linalg.LinAlgError:
            break
        cost = yy - float(projected @ theta)
        jacobian = (basis @ theta[:n_basis]) * slopes[0]  # ∂model/∂x with the field as solved
        dx, information, fisher = profiled_step(jacobian, weighted, weights, yw, theta, normal, normal,
                                                settings.max_step_mm)
        x += dx
        if abs(dx) < settings.tolerance_mm:
            break
    chi2 = max(cost, 0.0) / max(n_used - theta.size - 1, 1.0)
    try:
        shape_precision = small_linalg.inv(small_linalg.inv(fisher)[2:-1, 2:-1])
    except np.linalg.LinAlgError:
        shape_precision = np.zeros((n_basis - 1, n_basis - 1))
    return FrameSolution(x, settings.sigma_gray * math.sqrt(chi2), information, iterations, float(theta[0]),
                         float(theta[n_basis]), chi2, start.rejected_px, True, 0.0, cost,
                         start.rejected_mask, start.rejected_weights_exact, True, theta[1:n_basis], shape_precision,
                         start.transient_px, start.transient_share, start.transient_at)
