"""Sequential tracking: the position of every frame by Gauss–Newton from the previous frame's.

Continuity of motion is what makes a periodic target usable: starting from x_{k−1}, a few
Gauss–Newton steps land on the right period as long as the stage moved less than about a quarter
period between frames. When that assumption breaks (a jump, a dropped burst of frames, a
disturbed image) the tracker must notice rather than report a position one period off: it checks
the step, the fit residual and, when a grating reading comes with the frame, the disagreement
with it, and re-acquires by a global search over one period.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from graytrack.core import effects
from graytrack.core.errors import TrackingError
from graytrack.core.evaluation import ClippedHarmonics, FastHarmonics, GeneralHarmonics, gram_polynomials
from graytrack.core.models.fourier import FourierModel
from graytrack.core.recording import Recording
from graytrack.core.solvers import FrameSolution, GeneralBatch, TrigPolyBatch

Progress = Callable[[float, str], None]
ACQUIRE_GRID_PER_PERIOD = 64


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
        self.fast_path = not effects.needs_general_path(model)
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
