"""Sequential tracking: the position of every frame by Gauss–Newton from the previous frame's.

Continuity of motion is what makes a periodic target usable: starting from x_{k−1}, a few
Gauss–Newton steps land on the right period as long as the stage moved less than about a quarter
period between frames. When that assumption breaks (a jump, a dropped burst of frames, a
disturbed image) the tracker must notice rather than report a position one period off: it checks
the step, the fit residual and, when a grating reading comes with the frame, the disagreement
with it, and re-acquires by a global search over one period.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from graytrack.core.errors import TrackingError
from graytrack.core.models.fourier import TWO_PI, FourierModel
from graytrack.core.recording import Recording

Progress = Callable[[float, str], None]
ACQUIRE_GRID_PER_PERIOD = 64


@dataclass
class FrameSolution:
    x_mm: float
    rms_gray: float
    information: float  # Σ (∂F/∂x)² after any per-frame nuisance is profiled out
    iterations: int
    gain: float = 1.0
    offset: float = 0.0


@dataclass
class LockEvent:
    frame: int
    reason: str
    x_before_mm: float
    x_after_mm: float
    reacquired: bool


@dataclass
class TrackResult:
    x_mm: np.ndarray
    locked: np.ndarray
    rms_gray: np.ndarray
    crlb_mm: np.ndarray
    iterations: np.ndarray
    gain: np.ndarray
    offset: np.ndarray
    events: list[LockEvent] = field(default_factory=list)

    def error_um(self, reference: np.ndarray) -> np.ndarray:
        """Position minus reference in µm (NaN where either is missing)."""
        return (self.x_mm - reference) * 1e3


class ClippedHarmonics:
    """Wraps an evaluator so that saturated pixels stick at the limit with zero slope."""

    def __init__(self, inner: "FastHarmonics | GeneralHarmonics", model: FourierModel):
        self.inner, self.model = inner, model

    def evaluate(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.model.clip_with_slope(*self.inner.evaluate(x_mm))


class FastHarmonics:
    """F(x) and ∂F/∂x without a single sine of a pixel array: O(L·M·R·n) per call.

    Every pixel's Fourier series is folded into complex weights V_{l,h} (pixel offsets and flat
    field included), one set per stroke polynomial l; an evaluation is z^h (M scalars) and the
    stroke polynomials (L scalars) times V.
    """

    def __init__(self, model: FourierModel):
        weights = model.spatial_weights()  # (R, n, A, L)
        gain, offset = model.response()
        gain = np.broadcast_to(np.asarray(gain, dtype=np.float64), weights.shape[:2])
        harmonics = np.arange(1, model.harmonics + 1)
        shift = np.exp(1j * TWO_PI / model.period_mm * model.target_offset()[..., None] * harmonics)  # (R, n, M)
        sin_c, cos_c = weights[..., 1::2, :], weights[..., 2::2, :]  # (R, n, M, L)
        folded = (cos_c - 1j * sin_c) * (shift * gain[..., None])[..., None]
        n_values = weights.shape[0] * weights.shape[1]
        self.model = model
        self.period_mm = model.period_mm
        self.harmonics = harmonics
        self.offset = np.broadcast_to(np.asarray(offset, dtype=np.float64), weights.shape[:2]).reshape(-1)
        self.constants = (gain[..., None] * weights[..., 0, :]).reshape(n_values, -1).T.copy()  # (L, P)
        self.vs = folded.reshape(n_values, model.harmonics, -1).transpose(2, 1, 0).copy()  # (L, M, P)
        # The stroke-independent case, as the fast tracking path reads it:
        self.constant = self.constants[0] + self.offset
        self.v = self.vs[0]
        self.dv = self.v * (1j * TWO_PI / model.period_mm * harmonics)[:, None]

    def evaluate(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values and slopes ``(G, P)`` at positions ``x_mm`` ``(G,)``."""
        x_mm = np.asarray(x_mm, dtype=np.float64)
        z = np.exp(1j * TWO_PI / self.period_mm * np.outer(x_mm, self.harmonics))  # (G, M)
        if self.vs.shape[0] == 1:
            return self.constant + (z @ self.v).real, (z @ self.dv).real
        stroke, dstroke = self.model.stroke_basis(x_mm)  # (G, L)
        dz = z * (1j * TWO_PI / self.period_mm * self.harmonics)
        base = self.constants[None] + np.einsum("gm,lmp->glp", z, self.vs).real
        turning = np.einsum("gm,lmp->glp", dz, self.vs).real
        values = self.offset + np.einsum("gl,glp->gp", stroke, base)
        slopes = np.einsum("gl,glp->gp", stroke, turning) + np.einsum("gl,glp->gp", dstroke, base)
        return values, slopes


class GeneralHarmonics:
    """Fallback for models with a target map: the model's own predict."""

    def __init__(self, model: FourierModel):
        self.model = model

    def evaluate(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        values, slopes = self.model.predict(np.asarray(x_mm), with_derivative=True)
        return values.reshape(len(x_mm), -1), slopes.reshape(len(x_mm), -1)


class GeneralBatch:
    """Gauss–Newton on frames with any model: per iteration one model evaluation at one x.

    Handles what the fast path cannot: coefficients that drift along the stroke, a per-frame
    gain/offset solved together with x, and saturated pixels.
    """

    def __init__(self, model: FourierModel, prepared: np.ndarray, max_iterations: int, tolerance_mm: float,
                 evaluator: "FastHarmonics | GeneralHarmonics | ClippedHarmonics"):
        self.model = model
        self.frames = prepared.reshape(prepared.shape[0], -1)
        self.evaluator = evaluator
        self.max_iterations, self.tolerance_mm = max_iterations, tolerance_mm
        self.max_step_mm = model.period_mm / 4.0

    def refine(self, k: int, x_start: float) -> FrameSolution:
        y = self.frames[k]
        x, gain, offset = float(x_start), 1.0, 0.0
        common_mode = self.model.common_mode
        iterations = 0
        for iterations in range(1, self.max_iterations + 1):
            values, slopes = self.evaluator.evaluate(np.array([x]))
            values, slopes = values[0], slopes[0]
            residual = y - (gain * values + offset)
            if common_mode:
                jac = np.stack([gain * slopes, values, np.ones_like(values)], axis=1)
                delta = np.linalg.solve(jac.T @ jac, jac.T @ residual)
                dx = float(delta[0])
                gain, offset = gain + float(delta[1]), offset + float(delta[2])
            else:
                dx = float(slopes @ residual) / float(slopes @ slopes)
            dx = min(max(dx, -self.max_step_mm), self.max_step_mm)
            x += dx
            if abs(dx) < self.tolerance_mm:
                break
        values, slopes = self.evaluator.evaluate(np.array([x]))
        residual = y - (gain * values[0] + offset)
        rms = float(np.sqrt(residual @ residual / y.size))
        return FrameSolution(x, rms, self._information(values[0], slopes[0], gain), iterations, gain, offset)

    def _information(self, values: np.ndarray, slopes: np.ndarray, gain: float) -> float:
        d_x = gain * slopes
        info = float(d_x @ d_x)
        if self.model.common_mode:
            nuisance = np.stack([values, np.ones_like(values)], axis=1)
            cross = nuisance.T @ d_x
            info -= float(cross @ np.linalg.solve(nuisance.T @ nuisance, cross))
        return info

    def grid_cost(self, k: int, grid: np.ndarray) -> np.ndarray:
        values, _ = self.evaluator.evaluate(grid)
        y = self.frames[k]
        if not self.model.common_mode:
            return ((y[None] - values) ** 2).sum(axis=1)
        centred_v = values - values.mean(axis=1, keepdims=True)
        centred_y = y - y.mean()
        scale = (centred_v @ centred_y) / np.maximum((centred_v**2).sum(axis=1), 1e-300)
        return ((centred_y[None] - scale[:, None] * centred_v) ** 2).sum(axis=1) + 1e12 * (scale <= 0)


class TrigPolyBatch:
    """The fast path: each frame reduced to M complex numbers, then a scalar solve per frame.

    For a model whose coefficients do not depend on x, every quantity Gauss–Newton needs is a
    trigonometric polynomial in x: y·F(x) = y·c + Re Σ_h β_h z^h with β = V·y (one matrix product
    for all frames), and ‖F‖², ‖F′‖² have frame-independent coefficients (found once by FFT).
    The per-frame loop then does a few dozen scalar operations instead of array work.
    """

    def __init__(self, model: FourierModel, prepared: np.ndarray, max_iterations: int, tolerance_mm: float,
                 fast: FastHarmonics, gram: tuple[np.ndarray, np.ndarray]):
        frames = prepared.reshape(prepared.shape[0], -1)
        self.n_values = frames.shape[1]
        self.omega = TWO_PI / model.period_mm
        self.max_iterations, self.tolerance_mm = max_iterations, tolerance_mm
        self.max_step_mm = model.period_mm / 4.0
        self.harmonics = model.harmonics
        self.beta = frames @ fast.v.T  # (K, M)
        self.y_dot_c = frames @ fast.constant
        self.y_norm = np.einsum("kp,kp->k", frames, frames)
        self.q, self.d = gram
        degree = 2 * self.harmonics
        orders = np.arange(1, degree + 1)
        padded_beta = np.zeros((frames.shape[0], degree), dtype=complex)
        padded_beta[:, : self.harmonics] = self.beta
        # Per frame, as coefficients of z^1..z^2M:
        #   F′·(y − F) = Re Σ step_m z^m        (the Gauss–Newton numerator)
        #   ‖y − F‖² = cost_0 + Re Σ cost_m z^m
        step = padded_beta * (1j * self.omega * orders) - 0.5 * self.q[1:] * (1j * self.omega * orders)
        self._step_rows = step.tolist()
        self._cost_rows = (self.q[1:] - 2.0 * padded_beta).tolist()
        self._cost_const = (self.y_norm - 2.0 * self.y_dot_c + self.q[0].real).tolist()
        self._info_coeffs = self.d[1:].tolist()
        self._info_const = float(self.d[0].real)

    def refine(self, k: int, x_start: float) -> FrameSolution:
        step_coeffs, info_coeffs = self._step_rows[k], self._info_coeffs
        omega, degree, max_step = self.omega, 2 * self.harmonics, self.max_step_mm
        x = float(x_start)
        iterations = 0
        powers: list[complex] = []
        information = 1.0
        for iterations in range(1, self.max_iterations + 1):
            powers = _powers(cmath.exp(1j * omega * x), degree)
            numerator = sum([(c * p).real for c, p in zip(step_coeffs, powers)])
            information = self._info_const + sum([(c * p).real for c, p in zip(info_coeffs, powers)])
            dx = min(max(numerator / information, -max_step), max_step)
            x += dx
            if abs(dx) < self.tolerance_mm:
                break
        # Residual and information at the last evaluated point: the final step is below tolerance.
        cost = self._cost_const[k] + sum([(c * p).real for c, p in zip(self._cost_rows[k], powers)])
        return FrameSolution(x, math.sqrt(max(cost, 0.0) / self.n_values), information, iterations)

    def grid_cost(self, k: int, grid: np.ndarray) -> np.ndarray:
        z = np.exp(1j * self.omega * np.outer(grid, np.arange(2 * self.harmonics + 1)))  # (G, 2M+1)
        model_norm = (z @ self.q).real
        cross = self.y_dot_c[k] + (z[:, 1:self.harmonics + 1] @ self.beta[k]).real
        return self.y_norm[k] - 2.0 * cross + model_norm


def gram_polynomials(fast: FastHarmonics, model: FourierModel) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients of ‖F(x)‖² and ‖F′(x)‖² as trig polynomials of degree 2M (sampled + FFT)."""
    n_samples = 4 * model.harmonics + 4
    x = np.arange(n_samples) * model.period_mm / n_samples
    values, slopes = fast.evaluate(x)
    out = []
    for sampled in ((values**2).sum(axis=1), (slopes**2).sum(axis=1)):
        spectrum = np.fft.fft(sampled) / n_samples
        coeffs = 2.0 * spectrum[: 2 * model.harmonics + 1]
        coeffs[0] = spectrum[0].real
        out.append(coeffs)
    return out[0], out[1]


def _powers(z: complex, count: int) -> list[complex]:
    """[z, z², …, z^count]."""
    out = [z]
    for _ in range(count - 1):
        out.append(out[-1] * z)
    return out


class Tracker:
    """Per-frame solver bound to one calibrated model; holds no frame state of its own."""

    def __init__(self, model: FourierModel, max_iterations: int = 5, tolerance_mm: float = 1e-6,
                 residual_limit_gray: float | None = None):
        if not model.is_calibrated:
            raise TrackingError("the model has no coefficients: calibrate it first")
        self.model = model
        self.max_iterations = max_iterations
        self.tolerance_mm = tolerance_mm
        self.quarter_period_mm = model.period_mm / 4.0
        calibration_rmse = float(model.info.get("calibration_rmse_gray", model.noise_gray or 1.0))
        self.residual_limit_gray = residual_limit_gray or 3.0 * calibration_rmse + 1.0
        # Model-level work, done once: live tracking builds a one-frame batch per frame.
        evaluator = FastHarmonics(model) if model.target_map is None else GeneralHarmonics(model)
        self.fast_path = (model.stroke_degree == 0 and not model.common_mode and model.clip_gray is None
                          and model.target_map is None)
        self.gram = gram_polynomials(evaluator, model) if self.fast_path else None
        self.evaluator = evaluator if model.clip_gray is None else ClippedHarmonics(evaluator, model)

    def batch(self, prepared: np.ndarray) -> GeneralBatch | TrigPolyBatch:
        """Frames ``(K, R, n)`` in the model's row layout, reduced for solving."""
        if self.fast_path:
            return TrigPolyBatch(self.model, prepared, self.max_iterations, self.tolerance_mm, self.evaluator, self.gram)
        return GeneralBatch(self.model, prepared, self.max_iterations, self.tolerance_mm, self.evaluator)

    def frame_sigma(self, frame_rows: int) -> float:
        """Noise of one model row when ``frame_rows`` raw rows feed the model (averaging lowers it)."""
        return (self.model.noise_gray or 1.0) / np.sqrt(self.model.rows_averaged(frame_rows))

    def acquire(self, batch: GeneralBatch | TrigPolyBatch, k: int, lo_mm: float, hi_mm: float) -> FrameSolution:
        """Global search on a grid over ``[lo, hi]`` (at least one period), then Gauss–Newton."""
        count = max(int(np.ceil((hi_mm - lo_mm) / self.model.period_mm * ACQUIRE_GRID_PER_PERIOD)), 8)
        grid = np.linspace(lo_mm, hi_mm, count, endpoint=False)
        return batch.refine(k, float(grid[int(np.argmin(batch.grid_cost(k, grid)))]))

    def acquire_near(self, batch: GeneralBatch | TrigPolyBatch, k: int, anchor_mm: float) -> FrameSolution:
        half = self.model.period_mm / 2.0
        return self.acquire(batch, k, anchor_mm - half, anchor_mm + half)

    def lost_reason(self, solution: FrameSolution, x_prev: float, reference: float) -> str | None:
        if abs(solution.x_mm - x_prev) > self.quarter_period_mm:
            return f"step of {solution.x_mm - x_prev:+.3f} mm exceeds a quarter period"
        if solution.rms_gray > self.residual_limit_gray:
            return f"residual {solution.rms_gray:.2f} gray exceeds {self.residual_limit_gray:.2f}"
        if np.isfinite(reference) and abs(solution.x_mm - reference) > self.quarter_period_mm:
            return f"disagrees with the grating by {solution.x_mm - reference:+.3f} mm"
        return None


@dataclass
class SequentialState:
    """What carries from one frame to the next: the last position, its velocity, the lock."""

    x_prev: float | None = None
    velocity: float = 0.0  # mm per frame, from the last two locked frames: a better start than x_{k−1}
    locked: bool = False
    frame: int = 0
    events: list[LockEvent] = field(default_factory=list)

    def advance(self, tracker: "Tracker", batch: GeneralBatch | TrigPolyBatch, k: int,
                reference: float) -> tuple[FrameSolution, bool, bool]:
        """Solve batch frame ``k`` as the next frame of the sequence: (solution, placed, locked)."""
        events_before = len(self.events)
        solution, ok = _solve_frame(tracker, batch, k, self.x_prev, self.velocity, reference, self.events, self.frame)
        locked = ok and len(self.events) == events_before
        self.velocity = solution.x_mm - self.x_prev if locked and self.locked and self.x_prev is not None else 0.0
        if ok:
            self.x_prev = solution.x_mm
        self.locked, self.frame = locked, self.frame + 1
        return solution, ok, locked


def track(model: FourierModel, source: Recording | np.ndarray, reference: np.ndarray | None = None,
          x0_mm: float | None = None, progress: Progress | None = None, tracker: Tracker | None = None) -> TrackResult:
    """Track every frame of a recording (or a frame array) sequentially.

    Starts from ``x0_mm``, else from the first finite reference, else acquires on its own over
    the calibrated stroke. Frames that cannot be placed on a period are NaN, never a guess.
    """
    if isinstance(source, Recording):
        frames, reference = source.frames, source.reference if reference is None else reference
    else:
        frames = source
    frames = np.asarray(frames)
    prepared = model.prepare(frames)
    n_frames = prepared.shape[0]
    reference = np.full(n_frames, np.nan) if reference is None else np.asarray(reference, dtype=np.float64)
    if reference.shape != (n_frames,):
        raise TrackingError(f"reference has shape {reference.shape}, expected ({n_frames},)")
    tracker = tracker or Tracker(model)
    sigma = tracker.frame_sigma(1 if frames.ndim == 2 else frames.shape[1])

    out = {key: np.full(n_frames, np.nan) for key in ("x", "rms", "info", "gain", "offset")}
    iterations = np.zeros(n_frames, dtype=np.int64)
    locked = np.zeros(n_frames, dtype=bool)
    state = SequentialState(x_prev=x0_mm if x0_mm is not None else (reference[0] if np.isfinite(reference[0]) else None))
    report_every = max(n_frames // 100, 1)
    batch = tracker.batch(prepared)
    for k in range(n_frames):
        solution, ok, locked[k] = state.advance(tracker, batch, k, reference[k])
        if ok:
            out["x"][k], out["rms"][k], out["info"][k] = solution.x_mm, solution.rms_gray, solution.information
            out["gain"][k], out["offset"][k] = solution.gain, solution.offset
            iterations[k] = solution.iterations
        if progress and k % report_every == 0:
            progress(k / n_frames, f"frame {k}/{n_frames}")
    if progress:
        progress(1.0, f"{n_frames} frames, {len(state.events)} lock event(s)")
    crlb = sigma / np.sqrt(np.where(out["info"] > 0, out["info"], np.nan))
    return TrackResult(out["x"], locked, out["rms"], crlb, iterations, out["gain"], out["offset"], state.events)


@dataclass
class LiveFix:
    """One frame's answer in live tracking (the daemon's position stream)."""

    x_mm: float  # NaN when the frame could not be placed
    locked: bool
    rms_gray: float
    crlb_mm: float
    event: LockEvent | None


class LiveTracker:
    """Frame-by-frame tracking for a running rig: the same solver and lock logic as :func:`track`."""

    def __init__(self, model: FourierModel, x0_mm: float | None = None):
        self.model = model
        self.tracker = Tracker(model)
        self.state = SequentialState(x_prev=x0_mm)

    def update(self, frame: np.ndarray, reference_mm: float = float("nan")) -> LiveFix:
        """Solve one frame ``(n,)`` or ``(R, n)``; ``reference_mm`` is the grating at that instant, if read."""
        frame = np.asarray(frame)
        rows = 1 if frame.ndim == 1 else frame.shape[0]
        batch = self.tracker.batch(self.model.prepare(frame.reshape((1,) + frame.shape)))
        events_before = len(self.state.events)
        solution, ok, locked = self.state.advance(self.tracker, batch, 0, float(reference_mm))
        event = self.state.events[-1] if len(self.state.events) > events_before else None
        crlb = self.tracker.frame_sigma(rows) / np.sqrt(solution.information) if solution.information > 0 else np.nan
        return LiveFix(solution.x_mm if ok else float("nan"), locked, solution.rms_gray, float(crlb), event)


def _solve_frame(tracker: Tracker, batch: GeneralBatch | TrigPolyBatch, k: int, x_prev: float | None,
                 velocity: float, reference: float, events: list[LockEvent],
                 frame: int) -> tuple[FrameSolution, bool]:
    """Batch frame ``k`` (frame ``frame`` of the sequence): continue from ``x_prev``; on any sign
    of lost lock, re-acquire and log it."""
    if x_prev is None or not np.isfinite(x_prev):
        lo, hi = tracker.model.stroke_range_mm
        if np.isfinite(reference):
            solution = tracker.acquire_near(batch, k, reference)
        else:
            solution = tracker.acquire(batch, k, lo, max(hi, lo + tracker.model.period_mm))
        ok = solution.rms_gray <= tracker.residual_limit_gray
        if frame > 0 or not ok:
            events.append(LockEvent(frame, "acquisition", float("nan"), solution.x_mm if ok else float("nan"), ok))
        return solution, ok
    solution = batch.refine(k, x_prev + velocity)
    reason = tracker.lost_reason(solution, x_prev, reference)
    if reason is None:
        return solution, True
    anchor = reference if np.isfinite(reference) else x_prev
    again = tracker.acquire_near(batch, k, anchor)
    ok = again.rms_gray <= tracker.residual_limit_gray and (
        not np.isfinite(reference) or abs(again.x_mm - reference) <= tracker.quarter_period_mm
    )
    events.append(LockEvent(frame, reason, x_prev, again.x_mm if ok else float("nan"), ok))
    return again, ok
