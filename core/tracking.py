"""Sequential tracking: the position of every frame by Gauss–Newton from the previous frame's.

Continuity of motion is what makes a periodic target usable: starting from x_{k−1}, a few
Gauss–Newton steps land on the right period as long as the stage moved less than about a quarter
period between frames. When that assumption breaks (a jump, a dropped burst of frames, a
disturbed image) the tracker must notice rather than report a position one period off: it checks
the step, the fit residual and, when a grating reading comes with the frame, the disagreement
with it, and re-acquires by a global search over one period.

The world also changes after calibration: the light (a lamp dims, the room light comes on), a
pixel (dust lands on the sensor, a glint), the scene itself. Each frame is solved as cheaply as
it allows: with the calibrated light unless its χ² asks for the light's gain and offset to be
solved too, by robust reweighting only when a pixel does not fit; and every frame's χ² against
the noise model feeds a running average that says when the model has gone stale.
"""

from __future__ import annotations

import dataclasses
import math
import operator
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from graytrack.core import attribution, frame_kernel, repeats, transients
from graytrack.core.chi2_curve import Chi2Curve
from graytrack.core.chi2_episode import RECENT, RecentChi2
from graytrack.core.compression import stream_bound_factor, stream_chi2_spread
from graytrack.core.errors import TrackingError
from graytrack.core.geometry_check import refusal
from graytrack.core.light_return import LIGHT_RETURN_CHI2, after_frame
from graytrack.core.kernels import TableEvaluator
from graytrack.core.evaluation import FastHarmonics, TrigTables
from graytrack.core.frame_tables import FrameTables
from graytrack.core.focus_solve import CurvatureTable, focus_solve, general_focus_solve
from graytrack.core.focus_solve import warm as focus_warm
from graytrack.core.focus_follow import STRUCTURE_PX2 as FOCUS_STRUCTURE_PX2
from graytrack.core.focus_follow import FocusFollow, followable
from graytrack.core.models.fourier import TWO_PI, FourierModel
from graytrack.core.moving_band import MovingBand, follow
from graytrack.core.period_rival import PeriodRival
from graytrack.core.period_rival import repeats as repeats_each_period
from graytrack.core.recording import Recording
from graytrack.core.stretch import FrameStretch
from graytrack.core.stretch_follow import StretchFollow, followed_stretch, stretch_follow
from graytrack.core.stream_focus import focus_factor
from graytrack.core.texture import Texture
from graytrack.core.validity import FAMILIES, FrameSign, Monitor, Watch, monitor_for
from graytrack.core.solvers import (CUT_SIGMA, TRANSIENT_MAX_WIDTH_SHARE, FrameSolution, GeneralBatch, SolverSettings,
                                    StaticWeights, TrigPolyBatch, field_basis, field_solve, gauss_newton, grid_cost,
                                    robust_solve)

Progress = Callable[[float, str], None]
ACQUIRE_GRID_PER_PERIOD = 64
AMBIGUITY_CHI2 = 25.0  # a rival start within this χ² of the best one (5σ): the image cannot tell them apart
LIGHT_MODES = ("fixed", "auto", "free")
GAIN_RANGE = (0.2, 5.0)  # a solved light gain outside this is not the target seen under other light
MAX_REJECTED_FRACTION = 0.25  # a frame needing more pixels rejected than this is not trusted
STALE_WINDOW = 100  # frames: the χ² average that must rise for the model to be called stale
STALE_RATIO = 1.1  # a running χ² this much above calibration's: the model no longer describes the images
FIELD_WINDOW = 20  # frames: the average χ² gain of the light field that decides whether it is used
# A uniform light is nested in the field (2 more unknowns): the χ² it gains is χ²(2) when the light
# is uniform, mean 2 and spread 2; its average over the window beyond five of its spreads: a field.
FIELD_KEEP = 2.0 + 5.0 * 2.0 / math.sqrt(FIELD_WINDOW)
# A light's shape holds still: each frame's shape, against the running mean in units of its own
# noise, scatters as χ²/dof ≈ 1. Beyond five spreads of that average the field only mimics another
# change (defocus, a different print) and would hide it: the uniform light's answer is kept.
FIELD_SCATTER_LIMIT = 1.0 + 5.0 * math.sqrt(2.0 / (2 * FIELD_WINDOW))
# A uniform light is nested in the focus term (1 more unknown, the blur): the χ² it gains is χ²(1)
# when the focus holds, mean 1 and spread √2; its average over the window beyond five spreads: a blur.
FOCUS_KEEP = 1.0 + 5.0 * math.sqrt(2.0) / math.sqrt(FIELD_WINDOW)
# The field has one unknown more than the focus term and mimics a blur: it is taken over the focus
# only when, frame by frame, it gains more than the focus by more than that unknown's χ²(1), by
# five spreads of the window's average.
FIELD_BEYOND_FOCUS = FOCUS_KEEP
# One frame's χ² gain counts at most this much (a garbage frame cannot flip the average); the same
# cap for the field and the focus, or the comparison of their averages would be the caps'.
EVIDENCE_CAP = 10.0 * FIELD_KEEP
BLUR_LOOK_SPREADS = 3.0  # a free-light χ² average this many spreads high: the focus term is tried
BATCH_CHUNK = 4096  # frames reduced at a time (bounds memory on long recordings)


@dataclass
class LockEvent:
    frame: int
    reason: str
    x_before_mm: float
    x_after_mm: float
    reacquired: bool
    lost: bool = True  # False: an event that is no loss of lock (a repeated image, set aside)


@dataclass
class TrackResult:
    """Every frame's record as one array per quantity, and the lock events. A field named in
    core/frame_record.py is the quantity declared there (unit, type, meaning); here NaN stands for
    null and "" for no stale reason. The arrays beyond the first seven exist when tracking made them."""

    x_mm: np.ndarray
    locked: np.ndarray
    rms_gray: np.ndarray
    crlb_mm: np.ndarray
    iterations: np.ndarray
    gain: np.ndarray
    offset_gray: np.ndarray
    events: list[LockEvent] = field(default_factory=list)
    chi2: np.ndarray | None = None
    rejected_px: np.ndarray | None = None
    stale: np.ndarray | None = None
    chi2_calibration: float = float("nan")  # the calibration's own level, what χ² is compared with
    repeated: np.ndarray | None = None  # the image repeats the frame before bit for bit (given no position)
    stale_reason: np.ndarray | None = None
    transient_px: np.ndarray | None = None
    focus_px2: np.ndarray | None = None
    focus_sigma_px2: np.ndarray | None = None
    texture_px: np.ndarray | None = None
    texture: dict | None = None  # what the run learned on the print (Texture.summary; None: not learning)
    slide_sigma_um: np.ndarray | None = None

    def error_um(self, reference: np.ndarray) -> np.ndarray:
        """Position minus reference in µm (NaN where either is missing)."""
        return (self.x_mm - reference) * 1e3


@dataclass
class LightMemory:
    """What the solve of one frame tells the next: whether the light has changed, the last light,
    and the pixels it rejected (then the next frame starts robust, without them)."""

    free: bool = False
    fitted: int = 0  # free-light frames in a row on which the calibrated light fitted
    gain: float = 1.0
    offset: float = 0.0
    rejected: np.ndarray | None = None  # the pixels the last frame set aside
    field: bool = False  # a light field (shape across the line) is solved alongside the uniform light
    field_gain: float = 2.0  # running average of the χ² the field gains over the uniform light (from
    # the mean of χ²(2), what a uniform light leaves it: the evidence for a field must build up)
    field_shape: np.ndarray | None = None  # running average of the field's shape
    field_scatter: float = 1.0  # running average of each frame's shape against it, per dof in its noise
    uniform_chi2: float = 0.0  # running average of the uniform light's χ² while the field or focus is tried
    field_chi2: float | None = None  # running average of the field's own χ² (in the calibration's level)
    focus: bool = False  # a change of focus (blur) is solved alongside the uniform light
    focus_gain: float = 1.0  # running average of the χ² the focus term gains over the uniform light
    # (from the mean of χ²(1), what a steady focus leaves it)
    focus_track: FocusFollow = dataclasses.field(default_factory=FocusFollow)  # the last frames' focus
    focus_chi2: float | None = None  # running average of the focus term's own χ² (in the calibration's level)
    # (``field`` is this class's own attribute here, hence dataclasses.field)
    field_over_focus: float = 1.0  # running average of the χ² the field gains over the focus term (from
    # the mean of χ²(1), the field's one extra unknown, when the focus explains the frames)
    free_level: float = 1.0  # average χ² of the last free-light frames, in the calibration's level
    free_frames: int = 0  # how many frames that average holds (up to FIELD_WINDOW)
    moving: MovingBand | None = None  # a shadow's band moving across the field (core/moving_band.py)


class Tracker:
    """Per-frame solver bound to one calibrated model; holds no frame state of its own.

    ``light``: ``"fixed"`` keeps the calibrated light; ``"free"`` solves a gain and offset with x
    in every frame; ``"auto"`` solves them when a frame's χ² says the light changed, and keeps
    solving them until the calibrated light fits again (ten frames in a row: core/light_return.py); when a uniform
    light is not enough it also tries a light field and a change of focus (blur), and takes the one the evidence
    asks for.
    ``tolerance_mm``: the last Gauss–Newton step taken; it is applied, and what remains after it is that step times the
    contraction (≪ 1 on a converged frame), far below any bound. Default: ``"free"`` for a model with a
    per-frame common mode, else ``"fixed"``. ``robust``: frames whose χ² is beyond the noise are
    solved again by IRLS, so that a pixel gone bad in this run does not pull the position.
    ``follow_focus``: the focus term is also taken when the frames' focus estimates move (False: only
    when their χ² asks; the calibration's own run, whose focus is the model's by construction).
    """

    def __init__(self, model: FourierModel, max_iterations: int = 5, tolerance_mm: float = 1e-5,
                 residual_limit_gray: float | None = None, light: str | None = None, robust: bool = False,
                 follow_focus: bool = True):
        if not model.is_calibrated:
            raise TrackingError("the model has no coefficients: calibrate it first")
        light = light or ("free" if model.common_mode else "fixed")
        if light not in LIGHT_MODES:
            raise TrackingError(f"light mode must be one of {', '.join(LIGHT_MODES)}, got {light!r}")
        self.model, self.light, self.robust = model, light, robust
        # A model its own calibration refused (a reversed pixel axis, a wrong period: kept only to be
        # studied) places frames, but none of them is called locked.
        self.refused = refusal(model)
        self.quarter_period_mm = model.period_mm / 4.0
        sigma = model.noise_gray or 1.0
        self.chi2_curve = Chi2Curve.from_info(model.info)  # the level along the stroke (None: flat)
        self.repeats = repeats_each_period(model)  # no grating: placed up to whole periods (core/stroke_place.py)
        self.settings = SolverSettings(max_iterations, tolerance_mm, self.quarter_period_mm, sigma)
        calibration_rmse = float(model.info.get("calibration_rmse_gray", sigma))
        self.residual_limit_gray = residual_limit_gray or 3.0 * calibration_rmse + 1.0
        n_values = model.n_rows * model.n_pixels
        self.chi2_calibration = float(model.info.get("calibration_chi2", (calibration_rmse / sigma) ** 2))
        if not (math.isfinite(self.chi2_calibration) and self.chi2_calibration > 0):
            # every flag reads χ² against this level: NaN would call every frame fresh
            raise TrackingError(f"the model's calibration χ² is {self.chi2_calibration:g}: it cannot tell a frame "
                                "that fits from one that does not (every pixel masked, or no sample left); recalibrate")
        # a lossy stream's error is no white noise: its frames' χ² spreads as fewer samples' would
        # (core/compression.py stream_chi2_spread)
        independent = n_values / stream_chi2_spread(model.info) ** 2
        # beyond 5 standard deviations of one frame's χ² at the calibration's level: the frame asks
        self.chi2_limit = self.chi2_calibration * (1.0 + 5.0 * np.sqrt(2.0 / independent))
        # The running average's own spread is ≈ √(2/(window·pixels)) of the level; beyond five of
        # those the light is re-solved (a change too small for one frame to show), and beyond a
        # tenth more than calibration the model is called stale: its images are no longer these.
        # The flags' average is, until STALE_WINDOW frames have been seen, the plain mean of those
        # there are, judged against their spread (limits by the number of frames averaged, from 1):
        # started at calibration's level instead, a stream that never fits (a JPEG stream's first frames
        # at 9× the level, 80 of one frame's spreads) would be called fresh for its first 5-7 frames,
        # 4-11 bounds off.
        spreads = np.sqrt(2.0 / (np.arange(1, STALE_WINDOW + 1) * independent))
        self.sustained_limits = (self.chi2_calibration * (1.0 + 5.0 * spreads)).tolist()
        self.stale_limits = (self.chi2_calibration * (STALE_RATIO + 5.0 * spreads)).tolist()
        self.sustained_limit, self.stale_limit = self.sustained_limits[-1], self.stale_limits[-1]
        # A blur too small for one frame's χ² to ask for shows in the average χ² of the frames solved
        # with a free light (which the light cannot lower further). One frame's χ² alone passes the
        # running average's limit on a third of the frames and would have the focus solved for
        # nothing; the average of the last frames (up to FIELD_WINDOW), beyond three of its
        # spreads, asks for it. One frame counts at most the single-frame limit: a glint's frame
        # cannot hold the average up.
        self.free_frame_spread = float(np.sqrt(2.0 / independent))
        self.free_frame_cap = self.chi2_limit / self.chi2_calibration
        # Model-level work, done once: live tracking reduces one frame at a time.
        # Every model is the same expression of per-pixel tables (core/frame_tables.py), evaluated by
        # one compiled kernel. When every pixel is a trig polynomial in x (no stroke drift, target
        # map or clipping) the solver's moments also reduce to tables in z: a frame is then reduced
        # once and its iterations never touch a pixel again.
        self.frame_tables = FrameTables.of(model)
        self.evaluator = TableEvaluator(self.frame_tables)
        frame_kernel.warm(self.evaluator)  # the per-frame solve compiled (or loaded) now, not on a live frame
        self.fast_path = self.frame_tables.trig_polynomial
        self.tables = TrigTables(FastHarmonics(model), model) if self.fast_path else None
        noise = model.noise()
        self.signal_dependent = noise.signal_dependent
        self.static_weights = model.inverse_variance(np.zeros((model.n_rows, model.n_pixels))).reshape(1, -1)
        # each sample's weight beyond its noise (0: masked), flattened as the frame solves read it
        self.pixel_weight = np.ones(n_values) if model.pixel_weight is None else \
            np.ascontiguousarray(model.pixel_weight, dtype=np.float64).reshape(-1)
        self._static: dict[int, StaticWeights] = {}  # by rows averaged: what every frame shares
        # Robust tracking also sets aside samples stuck at the sensor's floor or ceiling (the
        # closed loop's plain tracking leaves them to its clipping effect, which models them).
        limits = model.info.get("sensor_range_gray") if robust else None
        self.sensor_range = None if limits is None else (float(limits[0]), float(limits[1]))
        self._masked = None if model.pixel_weight is None else (self.pixel_weight == 0)[None]
        self.field_basis = field_basis(model.n_rows, model.n_pixels) if light == "auto" else None
        self.layout = (model.n_rows, model.n_pixels)  # a prepared frame's samples: blobs are compact in it
        # The focus term lives on the fast path's moments (its one extra table), or on the model
        # evaluated at x for the others; both are ready before the first frame, so the first
        # blurred frame waits for neither a table nor the compiler.
        self.focus_capable = light == "auto"
        # its estimates' move alone asks for the focus term (core/focus_follow.py)
        self.focus_followed = self.focus_capable and follow_focus and followable(model.info)
        # the model's own error read as a focus, in the estimates' unit (core/focus_follow.py)
        self._focus_allowance = FOCUS_STRUCTURE_PX2 * model.pixel_pitch_mm**2
        # a lossy stream scatters each focus estimate this many of its white errors (core/stream_focus.py)
        self.focus_factor = focus_factor(model.info)
        self._curvature: CurvatureTable | None = None
        if self.focus_capable:
            if self.fast_path:
                self._curvature = CurvatureTable(self.tables, model.period_mm)
            focus_warm(self.evaluator, model.period_mm)

    def weights(self, prepared: np.ndarray, frame_rows: int) -> tuple[np.ndarray, bool]:
        """1/σ² per sample ``(K|1, P)``: the noise model at the observed gray level (the variance of
        a row mean when rows are averaged), zero on masked pixels and, when tracking robustly, on
        samples stuck at the sensor's floor or ceiling (saturated by more light than at
        calibration: they say nothing about x). The flag is True when these are the weights every frame shares,
        ``(1, P)``."""
        rows = self.model.rows_averaged(frame_rows)
        n_frames = prepared.shape[0]
        if self.signal_dependent and n_frames == 1:  # a live frame: one fused pass (core/frame_kernel.py),
            # the numbers of inverse_variance below (numpy's own passes are cheaper over a long batch)
            weights, _ = frame_kernel.sample_weights(prepared.reshape(n_frames, -1), self.model.pixel_noise,
                                                     self.pixel_weight, rows, self.sensor_range)
            return weights, False
        shared = not self.signal_dependent
        weights = self.static_weights * rows if shared else \
            self.model.inverse_variance(prepared).reshape(n_frames, -1) * rows
        if self.sensor_range is not None:
            inside = self.inside_range(prepared.reshape(n_frames, -1))
            if not inside.all():
                weights, shared = weights * inside, False
        return weights, shared

    def prepare(self, frames: np.ndarray) -> np.ndarray:
        """Raw frames ``(K, n)`` or ``(K, R, n)`` in the model's row layout (``model.prepare``). When
        tracking robustly, a row mean over a sample at the sensor's floor or ceiling is that limit
        itself, and so set aside with the samples stuck there: a mean over a clipped sample is biased
        by the clip, and calibration used no such column (the row mean is usable only where every
        row is). A 16-row strip saturating on some rows had the shared model 2-5x off its bound."""
        prepared = self.model.prepare(frames)
        if self.sensor_range is None or self.model.n_rows != 1 or np.ndim(frames) != 3 or np.shape(frames)[1] == 1:
            return prepared
        lo, hi = self.sensor_range
        high = (frames >= hi).any(axis=1, keepdims=True)
        low = (frames <= lo).any(axis=1, keepdims=True)
        if high.any() or low.any():
            prepared = np.where(high, hi, np.where(low, lo, prepared))
        return prepared

    def clipped_rows(self, frame: np.ndarray) -> bool:
        """Whether a strip frame ``(R, n)`` that a one-row model averages has a sample at the sensor's
        limits (:meth:`prepare` then sets its column aside)."""
        if self.sensor_range is None or self.model.n_rows != 1 or frame.ndim != 2 or frame.shape[0] == 1:
            return False
        lo, hi = self.sensor_range
        return bool(frame.max() >= hi or frame.min() <= lo)

    def inside_range(self, flat: np.ndarray) -> np.ndarray:
        """Samples ``(K, P)`` inside the sensor's range, or masked (they read 0 and carry no weight
        anyway: a masked dead pixel must not cost every frame the weights all frames share)."""
        lo, hi = self.sensor_range
        inside = (flat > lo) & (flat < hi)
        return inside if self._masked is None else np.logical_or(inside, self._masked, out=inside)

    def batch(self, prepared: np.ndarray, frame_rows: int = 1,
              raw: np.ndarray | None = None) -> GeneralBatch | TrigPolyBatch:
        """Frames ``(K, R, n)`` in the model's row layout, reduced for solving. ``raw``: the strip
        frames themselves, kept when the model averages their rows, so that a transient on a few
        rows is set aside on those rows only (:meth:`_rows_refined`)."""
        weights, shared = self.weights(prepared, frame_rows)
        if not self.fast_path:
            batch: GeneralBatch | TrigPolyBatch = GeneralBatch(self.evaluator, prepared, weights) \
                if prepared.shape[0] > 1 else GeneralBatch.one(self.evaluator, prepared.reshape(1, -1), weights)
        elif not shared:
            batch = TrigPolyBatch(self.tables, prepared, weights, evaluator=self.evaluator)
        else:
            static = self._static.get(frame_rows)
            if static is None:
                static = self._static[frame_rows] = StaticWeights.of(self.tables, weights)
            batch = TrigPolyBatch(self.tables, prepared, static.weights, static, self.evaluator)
        if raw is not None and self.model.n_rows == 1 and frame_rows > 1:
            batch.raw = np.asarray(raw)
        return batch

    def solve(self, batch: GeneralBatch | TrigPolyBatch, k: int, x_start: float, memory: LightMemory,
              reference: float = math.nan) -> FrameSolution:
        """Frame ``k`` from ``x_start``: the light and robustness the frame asks for, cheapest first
        (what the last frame needed, then the light solved, then the robust solve). ``reference``:
        the grating's reading, where a shadow's band is first looked for (core/moving_band.py)."""
        # A model fitted with a gain and offset per frame knows the light moves from frame to frame
        # (flicker, auto-exposure, row banding): "auto" then solves it in every frame, as calibration did.
        free = self.free_light(memory)
        robust_first = self.robust and memory.rejected is not None
        solution = self._attempt(batch, k, x_start, memory, free, robust_first)
        here = self.chi2_level(solution.x_mm, reference)
        limit = self.chi2_limit * here
        asked = solution.chi2 > limit
        # The light is asked for beyond the calibration's mean level even where its own frames fitted
        # worse: a seed model calibrated under a hunting gain has its level 100x at the stroke's start,
        # and frames there at 134x held the light, 4-13 bounds off.
        if solution.chi2 > self.chi2_limit * min(here, 1.0) and self.light == "auto" and not free:
            free = True
            solution = self._attempt(batch, k, x_start, memory, free, robust_first)
        freed_here = free and self.light == "auto" and not (memory.free or self.model.common_mode)
        if solution.chi2 > limit and self.robust and not robust_first:
            solution = self._attempt(batch, k, x_start, memory, free, True)
        if freed_here and solution.rejected_px and solution.free_light and solution.light_excess <= LIGHT_RETURN_CHI2:
            # The light was freed for samples that turned out to be outliers (a glint): with them out the
            # calibrated light fits, and solving it would only cost the frame information.
            start = FrameSolution(solution.x_mm, float("nan"), 0.0, 0)
            solution = robust_solve(batch, k, start, False, self.settings, solution.rejected_mask, self.chi2_limit,
                                    self.layout)
        if solution.transient_px and batch.raw is not None:
            solution = self._rows_refined(batch, k, solution)
        stays, memory.fitted = after_frame(memory.fitted, solution.free_light, solution.light_excess)
        memory.free = self.light == "auto" and stays
        memory.gain, memory.offset = solution.gain, solution.offset_gray
        memory.rejected = solution.rejected_mask if solution.rejected_px else None
        young = None
        if self.focus_capable:  # (light "auto") a light feature moving across the field, followed: no
            # evidence for a blur or a field of the frame's own (core/moving_band.py)
            if memory.moving is None:
                memory.moving = MovingBand(self.model.n_rows, self.model.n_pixels)
            # a blur the focus follower measures and the focus term describes is no band: its residual, fitted
            # as a band a few % deep, placed a 16-row focus cycle's second rise 3-9 bounds off (1.6x the bound)
            blurred = not memory.moving.active and self._focus_moved(memory)
            followed = solution if blurred else follow(self, batch, k, x_start, solution, memory.moving, here,
                                                       reference)
            if followed is not solution and memory.moving.moved:
                memory.focus_track.wait()
                return followed
            # a band not yet seen to move answers its first frames; the rest of the frame's bookkeeping (the
            # focus follower's) goes on as for the uniform answer (taken over, it swung a smudge's run 8 µm off)
            young = followed if followed is not solution else None
        if solution.free_light and math.isfinite(solution.chi2):
            memory.free_frames = min(memory.free_frames + 1, FIELD_WINDOW)
            level = min(solution.chi2 / (self.chi2_calibration * here), self.free_frame_cap)
            memory.free_level += (level - memory.free_level) / memory.free_frames
        if self.focus_capable and (asked or (solution.free_light and self._blur_suspected(memory))):
            memory.focus = True  # the frame did not fit as at calibration: a blur is one cheap unknown away
        tried_field = memory.field and self.field_basis is not None
        tried_focus = memory.focus and self.focus_capable
        # The focus is measured on every frame (core/focus_follow.py): a blur moves x before χ² shows it
        if tried_field or self.focus_capable:
            solution = self._changed(batch, k, solution, memory, tried_field, tried_focus, here)
        return solution if young is None else young

    def free_light(self, memory: LightMemory) -> bool:
        """Whether the next frame solves the light's gain and offset with x."""
        return self.light == "free" or (self.light == "auto" and (memory.free or self.model.common_mode))

    def chi2_level(self, x_mm: float, reference: float = 0.0) -> float:
        """The calibration's χ² level where a frame was placed, relative to its mean (1 without a
        curve, or off the map): a frame's χ² is held against it (core/chi2_curve.py). A frame without a
        grating ``reference`` of a model that repeats once a period may be any whole period away: the
        highest level there."""
        curve = self.chi2_curve
        if curve is None or not math.isfinite(x_mm):
            return 1.0
        if math.isfinite(reference) or not self.repeats:
            return curve.at(x_mm)
        return curve.anywhere(x_mm, self.model.period_mm)

    def _blur_suspected(self, memory: LightMemory) -> bool:
        """The free-light frames' average χ² beyond three of its spreads above the calibration's."""
        spread = self.free_frame_spread / math.sqrt(memory.free_frames)
        return memory.free_level > 1.0 + BLUR_LOOK_SPREADS * spread

    def _rows_refined(self, batch: GeneralBatch | TrigPolyBatch, k: int, line: FrameSolution) -> FrameSolution:
        """A transient found in the row mean of a strip, set aside row by row: a glint on 4 rows of
        16 costs those 4 rows' samples, not whole columns. The blob is found again in the raw rows
        (with samples at the sensor's limits, which a row mean hides); each column's mean is taken
        over the rows kept, with the information of that many rows, and the frame solved again
        (robustly: a bad pixel's column stays out). ``transient_px`` counts raw samples then."""
        model = self.model
        raw = np.asarray(batch.raw[k], dtype=np.float64)  # (R, n)
        values = self.evaluator.evaluate(np.array([line.x_mm]))[0][0]
        predicted = np.broadcast_to(line.gain * values + line.offset_gray, raw.shape)
        per_sample = model.inverse_variance(predicted)  # 1/σ² of one raw sample, 0 on masked pixels
        used = per_sample > 0.0
        size = np.abs(raw - predicted) * np.sqrt(per_sample)
        size /= max(1.0, 1.4826 * float(np.median(size[used]))) if used.any() else 1.0
        blob = transients.compact_blobs(size[None], CUT_SIGMA, max_width_share=TRANSIENT_MAX_WIDTH_SHARE)[0]
        out = blob.copy()
        if self.sensor_range is not None:
            out |= (raw <= self.sensor_range[0]) | (raw >= self.sensor_range[1])
        if not blob.any():
            return line
        keep = (per_sample * (used & ~out))
        weights = keep.sum(axis=0)  # the information of the kept rows' mean
        mean = np.where(weights > 0, (keep * raw).sum(axis=0) / np.maximum(weights, 1e-300), 0.0)
        if self.fast_path:
            single: GeneralBatch | TrigPolyBatch = TrigPolyBatch(self.tables, mean[None], weights[None],
                                                                  evaluator=self.evaluator)
        else:
            single = GeneralBatch.one(self.evaluator, mean[None], weights[None])
        start = FrameSolution(line.x_mm, float("nan"), 0.0, 0, line.gain, line.offset_gray)
        solution = robust_solve(single, 0, start, line.free_light, self.settings, None, self.chi2_limit, self.layout)
        solution.transient_px = int(blob.sum())
        solution.transient_share = float(blob.mean())
        solution.transient_at = float(np.nonzero(blob)[1].mean())
        return solution

    def _changed(self, batch: GeneralBatch | TrigPolyBatch, k: int, uniform: FrameSolution, memory: LightMemory,
                 tried_field: bool, tried_focus: bool, here: float = 1.0) -> FrameSolution:
        """The frame solved with a light field and/or a focus change as well as with the uniform
        light, and the answer the evidence asks for. Each is taken only while the uniform light's
        own χ² stays above the calibration's level and its χ² gain, averaged over the last frames,
        is beyond what its extra unknowns gain by chance. Both can follow a blur (the field by
        trading its shape against x): the field is taken only when it explains more than the focus
        by more than its one extra unknown, and its shape holds still. The focus estimate rides on
        whichever answer is taken, for the focus watch. ``here``: the calibration's χ² level where the
        frame is (core/chi2_curve.py), what the uniform light's χ² is held against."""
        uniform_chi2 = uniform.chi2 / here
        if memory.field_shape is None and memory.focus_gain <= FOCUS_KEEP:  # neither has built up evidence yet
            memory.uniform_chi2 = uniform_chi2
        memory.uniform_chi2 += (uniform_chi2 - memory.uniform_chi2) / STALE_WINDOW
        wanted = memory.uniform_chi2 > self.sustained_limit
        shaped = self._field(batch, k, uniform, memory, here) if tried_field else None
        measured = self._focus(batch, k, uniform, memory, here, tried_focus) if self.focus_capable else None
        focused = measured if tried_focus else None  # the focus term competes once the frames asked for it
        answer = uniform
        if shaped is not None and focused is not None:
            beyond = (focused.cost - shaped.cost) / self.chi2_calibration
            beyond = min(max(beyond, -EVIDENCE_CAP), EVIDENCE_CAP) if math.isfinite(beyond) else 0.0
            memory.field_over_focus += (beyond - memory.field_over_focus) / FIELD_WINDOW
        field_over_focus = focused is None or memory.field_over_focus > FIELD_BEYOND_FOCUS
        # ... and only a field that describes the images: one that leaves χ² above the calibration's
        # level explains some other change and trades its shape against x (a lamp dimmed on a model
        # whose per-pixel offsets the light gain then scaled too: the field's answers 2× their
        # sevenfold bound, 14 µm off on a 16-row strip at 0.41 µm, none flagged)
        explains = shaped is not None and memory.field_chi2 is not None and memory.field_chi2 <= self.sustained_limit
        if shaped is not None and memory.field and wanted and memory.field_scatter < FIELD_SCATTER_LIMIT \
                and field_over_focus and explains and self.untrusted(shaped) is None:
            answer = shaped
        elif focused is not None and memory.focus and (wanted or self._focus_moved(memory)) \
                and self.untrusted(focused) is None:
            answer = focused
            focused.chi2_calibrated_focus = uniform.chi2
        # a model whose focus is followed shows its estimates a while after the term was dropped (the
        # watch sees the focus come back); any other only those of the frames that tried it and kept it on:
        # one frame's χ² beyond its limit (a telegraph pixel's flip) tries the focus, whose gain then says no
        # (shown, a steady 16-row strip would report 85 such estimates, as a focus taken)
        # the watch's window opens on a try too, unless the estimates held the calibration's focus until then (a
        # focus that comes and goes is judged as it comes back: a 16-row focus cycle under --trim 1.04x its bound so,
        # 1.92x with the window opened by a kept term alone, the blur read as a stretch beside no focus)
        opened = tried_focus and not memory.focus_track.held(self._focus_allowance)
        showing = memory.focus_track.shown(opened or memory.focus)
        shown = measured is not None and ((tried_focus and memory.focus) or (showing and self.focus_followed))
        if shown and answer is uniform:  # under the field's answer the blur-only fit is no estimate
            answer.focus, answer.focus_sigma = measured.focus, measured.focus_sigma
        return answer

    def _focus(self, batch: GeneralBatch | TrigPolyBatch, k: int, uniform: FrameSolution,
               memory: LightMemory, here: float = 1.0, tried: bool = True) -> FrameSolution:
        """The frame with a change of focus profiled out, and the running evidence for it (``tried``:
        the focus term competes for this frame's answer; else it is only measured)."""
        model = self.model
        prior = memory.focus_track.prior()
        if not self.fast_path:
            focused = general_focus_solve(self.evaluator, batch.frames[k], batch.weights(k), uniform, self.settings,
                                          model.period_mm, model.pixel_pitch_mm, prior)
        else:
            if self._curvature is None:  # (a solver built without the focus term: light given)
                self._curvature = CurvatureTable(self.tables, model.period_mm)
            focused = focus_solve(batch, k, self._curvature, uniform, self.settings, model.pixel_pitch_mm, prior)
        focused.focus_sigma *= self.focus_factor  # the stream's scatter is in the estimate's error
        footprint = model.pixel_pitch_mm**2
        memory.focus_track.add(focused.focus * footprint, focused.focus_sigma * footprint)
        level_chi2 = focused.chi2 / here if math.isfinite(focused.chi2) else math.inf
        memory.focus_chi2 = level_chi2 if memory.focus_chi2 is None else \
            memory.focus_chi2 + (min(level_chi2, 3.0 * self.stale_limit) - memory.focus_chi2) / FIELD_WINDOW
        if not tried:  # measured only: the χ² it gains counts once the frames ask; the term holds where the focus moved
            memory.focus = self._focus_moved(memory)
            return focused
        # in what the focus term gains by chance: the calibration's level, or on a lossy stream, whose error lies
        # along the blur far more than the noise does, its estimates' scatter (core/stream_focus.py)
        chance = max(self.chi2_calibration, self.focus_factor**2) if self.focus_factor > 1.0 else self.chi2_calibration
        gained = (uniform.cost - focused.cost) / chance if math.isfinite(focused.cost) else 0.0
        gained = min(max(gained, 0.0), EVIDENCE_CAP)
        memory.focus_gain += (gained - memory.focus_gain) / FIELD_WINDOW
        memory.focus = memory.focus_gain > FOCUS_KEEP or self._focus_moved(memory)
        return focused

    def _focus_moved(self, memory: LightMemory) -> bool:
        """The focus estimates have moved (core/focus_follow.py) and the focus term describes the
        frames (its running χ² at the calibration's level): a blur, the focus term's answer whatever
        the uniform light's χ² says. A model that misses something else (a sensor's fixed pattern,
        stray light) leaves a residue part of which the blur direction takes: its estimates move
        too, but its χ² stays up (the seed model under 2 gray of DSNU: 4.3x its bound, 7.8x had the
        focus been taken)."""
        return self.focus_followed and memory.focus_track.moved(self._focus_allowance) \
            and memory.focus_chi2 is not None and memory.focus_chi2 <= self.sustained_limit

    def _field(self, batch: GeneralBatch | TrigPolyBatch, k: int, uniform: FrameSolution,
               memory: LightMemory, here: float = 1.0) -> FrameSolution:
        """The frame solved with a light field, and the running evidence for it: its χ² gain over
        the uniform light and how still its shape holds. Once the gain falls back, the field
        stops being solved."""
        weights = batch.weights(k)
        if uniform.rejected_px:
            weights = weights * ~uniform.rejected_mask
        shaped = field_solve(self.evaluator, batch.frames[k], weights, self.field_basis, uniform, self.settings)
        # In units of the calibration's own χ² level: where the model already left residue at
        # calibration, a difference of costs is that much larger without the light changing.
        level = self.chi2_calibration
        gained = (uniform.cost - shaped.cost) / level if math.isfinite(shaped.cost) else 0.0
        gained = min(max(gained, 0.0), EVIDENCE_CAP)
        memory.field_gain += (gained - memory.field_gain) / FIELD_WINDOW
        memory.field = memory.field_gain > FIELD_KEEP
        level_chi2 = shaped.chi2 / here if math.isfinite(shaped.chi2) else math.inf  # as the uniform light's
        memory.field_chi2 = level_chi2 if memory.field_chi2 is None else \
            memory.field_chi2 + (min(level_chi2, 3.0 * self.stale_limit) - memory.field_chi2) / FIELD_WINDOW
        if memory.field_shape is None:
            memory.field_shape, memory.field_scatter = shaped.shape.copy(), 1.0
        deviation = shaped.shape - memory.field_shape
        scatter = float(deviation @ shaped.shape_precision @ deviation) / (deviation.size * level)
        scatter = min(scatter, 10.0 * FIELD_SCATTER_LIMIT)
        memory.field_scatter += (scatter - memory.field_scatter) / FIELD_WINDOW
        memory.field_shape += deviation / FIELD_WINDOW
        if not memory.field:
            memory.field_shape = None
        return shaped

    def _attempt(self, batch: GeneralBatch | TrigPolyBatch, k: int, x_start: float, memory: LightMemory,
                 free: bool, robust: bool) -> FrameSolution:
        if not robust:
            return gauss_newton(batch, k, x_start, free, self.settings)
        start = FrameSolution(x_start, float("nan"), 0.0, 0, memory.gain, memory.offset)
        return robust_solve(batch, k, start, free, self.settings, memory.rejected, self.chi2_limit, self.layout)

    def acquire(self, batch: GeneralBatch | TrigPolyBatch, k: int, lo_mm: float, hi_mm: float,
                memory: LightMemory) -> FrameSolution:
        """Global search on a grid over ``[lo, hi]`` (at least one period), then the frame's solve.
        The search is blind to the light unless the light is held fixed."""
        return self.acquire_with_rival(batch, k, lo_mm, hi_mm, memory)[0]

    def acquire_with_rival(self, batch: GeneralBatch | TrigPolyBatch, k: int, lo_mm: float, hi_mm: float,
                           memory: LightMemory) -> tuple[FrameSolution, float | None]:
        """:meth:`acquire`, and how far away (mm) another start fits as well as the best (None: none).

        Over a stroke of several periods a periodic target shows the same image once a period:
        only what is not periodic (a target map, drift along the stroke) can tell the periods
        apart. The best grid point more than ¾ period from the best one is refined too; when the
        two fits differ by less than ``AMBIGUITY_CHI2`` the image alone cannot say which period
        the stage is in, and the better of the two is kept.
        """
        count = max(int(np.ceil((hi_mm - lo_mm) / self.model.period_mm * ACQUIRE_GRID_PER_PERIOD)), 8)
        grid = np.linspace(lo_mm, hi_mm, count, endpoint=False)
        free = self.light != "fixed"
        costs = grid_cost(batch, k, grid, free)
        starts: list[float] = []  # the best grid point of each period-sized neighbourhood
        for index in np.argsort(costs):
            if all(abs(grid[index] - x) > 0.75 * self.model.period_mm for x in starts):
                starts.append(float(grid[index]))
        if len(starts) == 1:
            return self.solve(batch, k, starts[0], memory), None
        # each refined where it converged: the rival's offset is then the models' own, which a layer
        # along the stroke makes other than a whole period (core/period_rival.py)
        refined = sorted((s.chi2, s.x_mm) for s in (gauss_newton(batch, k, x, free, self.settings) for x in starts))
        samples = batch.scalars(k)[3]
        (best_chi2, start), (next_chi2, other) = refined[0], refined[1]
        solution = self.solve(batch, k, start, memory)
        ambiguous = (next_chi2 - best_chi2) * samples < AMBIGUITY_CHI2
        return solution, (other - solution.x_mm if ambiguous else None)

    def acquire_near(self, batch: GeneralBatch | TrigPolyBatch, k: int, anchor_mm: float,
                     memory: LightMemory) -> FrameSolution:
        half = self.model.period_mm / 2.0
        return self.acquire(batch, k, anchor_mm - half, anchor_mm + half, memory)

    def explain(self, batch: GeneralBatch | TrigPolyBatch, k: int, solution: FrameSolution) -> dict:
        """The shapes in frame ``k``'s residual (core/attribution.py) and its largest samples: what
        the validity monitor asks when χ² has risen. Costs one evaluation at three positions."""
        step = self.model.period_mm * 1e-3
        values, slopes = self.evaluator.evaluate(np.array([solution.x_mm - step, solution.x_mm, solution.x_mm + step]))
        curvature = (slopes[2] - slopes[0]) / (2.0 * step)
        weights = batch.weights(k)
        if solution.rejected_mask is not None:
            weights = weights * ~solution.rejected_mask
        residual = batch.residuals(k, solution.x_mm, solution.gain, solution.offset_gray)
        phase = (TWO_PI / self.model.period_mm) * (solution.x_mm + self.model.target_offset().reshape(-1))
        columns = attribution.shapes(values[1], slopes[1], curvature, self.model.n_rows, phase, self.model.harmonics)
        squares = residual * residual * weights
        top = np.argpartition(squares, squares.size - max(2, squares.size // 50))[-max(2, squares.size // 50):]
        shares, coefficients = attribution.shares(residual, weights, columns)
        return {"shares": shares, "coefficients": coefficients, "top": top.tolist()}

    def untrusted(self, solution: FrameSolution) -> str | None:
        """Why a solution, wherever it lies, cannot be trusted (None when it can)."""
        if solution.rms_gray > self.residual_limit_gray:
            return f"residual {solution.rms_gray:.2f} gray exceeds {self.residual_limit_gray:.2f}"
        if solution.free_light and not GAIN_RANGE[0] < solution.gain < GAIN_RANGE[1]:
            return f"light gain {solution.gain:.2f} outside {GAIN_RANGE[0]:g}..{GAIN_RANGE[1]:g}"
        if solution.transient_share > MAX_REJECTED_FRACTION:
            return (f"a transient (glint, reflection, passing dust) covers {100 * solution.transient_share:.0f} % of "
                    f"the frame ({solution.transient_px} samples): too little left to trust the position")
        if solution.rejected_px > MAX_REJECTED_FRACTION * self.model.n_rows * self.model.n_pixels:
            return f"{solution.rejected_px} pixels rejected as outliers"
        return None

    def lost_reason(self, solution: FrameSolution, x_prev: float, reference: float) -> str | None:
        if abs(solution.x_mm - x_prev) > self.quarter_period_mm:
            return f"step of {solution.x_mm - x_prev:+.3f} mm exceeds a quarter period"
        reason = self.untrusted(solution)
        if reason:
            return reason
        if math.isfinite(reference) and abs(solution.x_mm - reference) > self.quarter_period_mm:
            return f"disagrees with the grating by {solution.x_mm - reference:+.3f} mm"
        return None


# A pending frame's entry (SequentialState._watch_validity), slot by slot, and the fields of its
# solution a sign reads (FrameSolution and FrameSign name them alike).
PENDING_SLOTS = ("frame", "solution", "reference_mm", "placed", "rows_averaged", "chi2_average", "chi2_suspect",
                 "chi2_stale", "explain", "stretch")
SOLUTION_SIGNS = ("chi2", "information", "gain", "offset_gray", "focus", "focus_sigma", "rejected_px", "transient_px",
                  "transient_at", "x_mm", "free_light", "field", "moving", "period_guess", "pulled")  # named alike
_solution_signs = operator.attrgetter(*SOLUTION_SIGNS)


@dataclass
class SequentialState:
    """What carries from one frame to the next: the last position, its velocity, the lock, the
    light, and the running χ² that tells whether the model still describes the images."""

    x_prev: float | None = None
    velocity: float = 0.0  # mm per frame, from the last two locked frames: a better start than x_{k−1}
    locked: bool = False
    frame: int = 0
    events: list[LockEvent] = field(default_factory=list)
    memory: LightMemory = field(default_factory=LightMemory)
    # The light control's: an exponential average over about STALE_WINDOW frames, started at calibration's level.
    chi2_average: float | None = None
    # The flags': the plain mean of the first frames (up to STALE_WINDOW of them, their count in
    # chi2_frames), then the same exponential average. Positions never read it.
    chi2_mean: float = 0.0
    chi2_frames: int = 0
    chi2_suspect: bool = False  # the average is beyond its own spread above calibration's level
    chi2_stale: bool = False  # ... and beyond the stale limit
    stale: bool = False  # the validity monitor says the model no longer holds (core/validity.py)
    stale_reason: str | None = None  # the family it blames
    monitor: Monitor | None = None  # made from the tracker at the first frame
    rows_averaged: int = 1  # raw rows behind each model row
    # Batch tracking: the frames' signs wait here, and the monitor takes them a chunk at a time
    # (:meth:`verdicts`); None: each frame is shown to the monitor as it is solved (live).
    pending: list | None = None
    recent: RecentChi2 = field(default_factory=RecentChi2)  # the last frames' χ²: has an episode ended?
    texture: Texture | None = None  # marks learned on the print in this run (core/texture.py); None: not learning
    # the lens's stretch followed and taken out of each frame (core/stretch_follow.py: a trim's); None: not
    stretch: StretchFollow | None = None
    rival: PeriodRival | None = None  # acquired without a grating, another period followed too (core/period_rival.py)

    def advance(self, tracker: "Tracker", batch: GeneralBatch | TrigPolyBatch, k: int,
                reference: float) -> tuple[FrameSolution, bool, bool]:
        """Solve batch frame ``k`` as the next frame of the sequence: (solution, placed, locked)."""
        events_before = len(self.events)
        texture, solved, at = self.texture, batch, k
        if texture is not None:  # the learned marks divided out of the frame where it should be
            guess = self.x_prev + self.velocity if self.locked else reference
            memory = self.memory
            solved, at = texture.corrected(tracker, batch, k, guess, tracker.free_light(memory), memory.gain,
                                           memory.offset)
        follow = self.stretch
        if follow is not None:
            guess = self.x_prev + self.velocity if self.locked else reference
            solved, at = follow.corrected(tracker, solved, at, guess, self.memory.gain)
        solution, ok = _solve_frame(tracker, solved, at, self, reference)
        if texture is not None:
            solution.pulled = ok and texture.pulls(solution)
        if follow is not None:
            follow.observe(tracker, solved, at, solution, ok)
        locked = ok and len(self.events) == events_before
        self.velocity = solution.x_mm - self.x_prev if locked and self.locked and self.x_prev is not None else 0.0
        if ok:
            self.x_prev = solution.x_mm
        self.locked, self.frame = locked, self.frame + 1
        # with a focus term solved, the model as calibrated is what the running χ² watches
        focus_free = solution.chi2_calibrated_focus
        chi2 = focus_free if math.isfinite(focus_free) else solution.chi2
        self._watch_model(tracker, chi2 / tracker.chi2_level(solution.x_mm, reference),  # the level where it was taken
                          not solution.field)
        self._watch_validity(tracker, solved, at, solution, ok, reference)
        if texture is not None:
            # the frame's place vouched for by its own fit: the running χ² at its level, nothing followed, the
            # marks not moving it (the monitor's verdicts come a chunk later in batch tracking: not read here)
            trusted = not (self.chi2_suspect or solution.moving or texture.pull_z_beyond)
            texture.observe(tracker, batch, k, solution, ok, self.frame - 1, reference, trusted)
        return solution, ok, locked and tracker.refused is None

    def _watch_validity(self, tracker: "Tracker", batch: GeneralBatch | TrigPolyBatch, k: int,
                        solution: FrameSolution, placed: bool, reference: float) -> None:
        if self.monitor is None:
            self.monitor = monitor_for(tracker)
        explain = (lambda: tracker.explain(batch, k, solution)) if placed and self.chi2_suspect else None
        stretched = FrameStretch(tracker, batch, k, solution) if placed else None  # core/stretch.py
        if placed and self.stretch is not None:  # measured already, with the stretch taken out added back
            stretched = followed_stretch(self.stretch)
        average = self.chi2_average if self.chi2_average is not None else float("nan")
        if self.pending is not None:
            self.pending.append((self.frame - 1, solution, reference, placed, self.rows_averaged, average,
                                 self.chi2_suspect, self.chi2_stale, explain, stretched))
            return
        sign = FrameSign(
            self.frame - 1, solution.chi2, solution.information, gain=solution.gain, offset_gray=solution.offset_gray,
            focus=solution.focus, focus_sigma=solution.focus_sigma, rejected_px=solution.rejected_px,
            transient_px=solution.transient_px, transient_at=solution.transient_at,
            x_mm=solution.x_mm, reference_mm=reference, placed=placed, rows_averaged=self.rows_averaged,
            free_light=solution.free_light, field=solution.field, chi2_average=average,
            chi2_suspect=self.chi2_suspect, chi2_stale=self.chi2_stale, explain=explain, stretch=stretched,
            moving=solution.moving, period_guess=solution.period_guess, pulled=solution.pulled)
        verdict = self.monitor.observe(sign)
        self.stale, self.stale_reason = verdict.stale, verdict.reason

    def verdicts(self) -> list[str | None]:
        """The monitor's reason (None: not stale) for each frame waiting in :attr:`pending`, in order,
        the monitor taking them all at once (:meth:`Monitor.observe_many`); the state's verdict is
        then the last one's. The frames' batch must still be the one they were solved in (a
        suspect frame's residual is read from it)."""
        pending, self.pending = self.pending or [], []
        if not pending:
            return []
        entries = list(zip(*pending))  # one tuple per slot of a pending entry
        columns = dict(zip(PENDING_SLOTS, map(list, entries)))
        del columns["solution"]
        columns.update(zip(SOLUTION_SIGNS, map(list, zip(*map(_solution_signs, entries[1])))))
        columns["information_calibrated"] = [float("nan")] * len(pending)
        reasons = self.monitor.observe_many(columns)
        self.stale, self.stale_reason = self.monitor.verdict.stale, self.monitor.verdict.reason
        return reasons

    def repeat(self) -> None:
        """The frame repeats the image before it (a driver's double delivery): it shows where the stage
        was, not where its timestamp says; no position, logged, and the sequence goes on past it."""
        self.events.append(LockEvent(self.frame, f"the image repeats frame {self.frame - 1} bit for bit (delivered "
                                                 "twice by the camera driver): no position for it",
                                     self.x_prev if self.x_prev is not None else float("nan"), float("nan"), False,
                                     lost=False))
        self.frame += 1

    def _watch_model(self, tracker: "Tracker", chi2: float, plain: bool = True) -> None:
        """A running χ² average (one frame's contribution capped, so that once the average has
        frames behind it a single garbage frame cannot flip it) above the stale limit: the images
        have left what the model describes. ``plain``: the answer needed no light field (a focus
        term's answer is watched by the uniform light's χ² already)."""
        if not math.isfinite(chi2):
            return
        capped = min(chi2, 3.0 * tracker.stale_limit)
        if self.chi2_average is None:
            self.chi2_average = tracker.chi2_calibration
        self.chi2_average += (capped - self.chi2_average) / STALE_WINDOW
        frames = self.chi2_frames = min(self.chi2_frames + 1, STALE_WINDOW)
        self.chi2_mean += (capped - self.chi2_mean) / frames
        # an episode that came and went (a shadow passing) is forgotten once it has left (core/chi2_episode.py)
        self.recent.add(capped, plain)
        limits = (tracker.chi2_calibration, tracker.sustained_limits)
        if (recent := self.recent.ended(self.chi2_mean, *limits)) is not None:
            self.chi2_mean, frames = recent, min(self.chi2_frames, RECENT)
            self.chi2_frames = frames
        if self.recent.ended(self.chi2_average, *limits) is not None:  # the light control starts again, as at
            self.chi2_average = self.memory.uniform_chi2 = tracker.chi2_calibration  # the run's start
        self.chi2_suspect = self.chi2_mean > tracker.sustained_limits[frames - 1]
        self.chi2_stale = self.chi2_mean > tracker.stale_limits[frames - 1]
        # The light control keeps the average started at calibration's level: a first frame's χ²
        # alone does not set the light, its field and the focus free (on a strip whose focus moved
        # since calibration that cost the run 1.7x its bound against 1.1x).
        if tracker.light == "auto" and self.chi2_average > tracker.sustained_limit:
            if self.memory.free:  # a uniform light was not enough: try its shape, and a change of focus
                self.memory.field = self.memory.focus = True
            self.memory.free = True  # the next frame re-solves the light; it stays so if the light changed


def track(model: FourierModel, source: Recording | np.ndarray, reference: np.ndarray | None = None,
          x0_mm: float | None = None, progress: Progress | None = None, tracker: Tracker | None = None,
          light: str | None = None, robust: bool = False, learn: bool = False,
          watches: Sequence[Watch] = ()) -> TrackResult:
    """Track every frame of a recording (or a frame array) sequentially.

    Starts from ``x0_mm``, else from the first finite reference, else acquires on its own over
    the calibrated stroke. Frames that cannot be placed on a period are NaN, never a guess.
    ``light`` and ``robust`` as for :class:`Tracker` (ignored when a ``tracker`` is given);
    ``watches`` as for :class:`LiveTracker` (``track --trim``'s scale watch and its trim).
    ``learn``: marks fixed to the print that arrive during the run are learned and their samples
    count again (core/texture.py).
    """
    if isinstance(source, Recording):
        frames, reference = source.frames, source.reference if reference is None else reference
    else:
        frames = source
    frames = np.asarray(frames)
    frame_rows = 1 if frames.ndim == 2 else frames.shape[1]
    n_frames = frames.shape[0]
    reference = np.full(n_frames, np.nan) if reference is None else np.asarray(reference, dtype=np.float64)
    if reference.shape != (n_frames,):
        raise TrackingError(f"reference has shape {reference.shape}, expected ({n_frames},)")
    tracker = tracker or Tracker(model, light=light, robust=robust)

    out = {key: np.full(n_frames, np.nan) for key in ("x", "rms", "info", "gain", "offset", "chi2", "focus",
                                                      "focus_sigma")}
    iterations = np.zeros(n_frames, dtype=np.int64)
    rejected = np.zeros(n_frames, dtype=np.int64)
    transient = np.zeros(n_frames, dtype=np.int64)
    locked = np.zeros(n_frames, dtype=bool)
    stale = np.zeros(n_frames, dtype=bool)
    stale_reason = np.full(n_frames, "", dtype=f"<U{max(map(len, FAMILIES))}")
    repeated = repeats.repeated(frames, model.noise_gray or 0.0)
    state = SequentialState(x_prev=x0_mm if x0_mm is not None else (
        reference[0] if n_frames and np.isfinite(reference[0]) else None),
        rows_averaged=model.rows_averaged(frame_rows), pending=[], monitor=monitor_for(tracker, watches),
        texture=Texture(model, MAX_REJECTED_FRACTION) if learn else None, stretch=stretch_follow(watches))
    texture_px = np.zeros(n_frames, dtype=np.int64)
    report_every = max(n_frames // 100, 1)
    batch = None
    for k in range(n_frames):
        if k % BATCH_CHUNK == 0:
            if k:
                _judge(state, repeated, stale, stale_reason, k - BATCH_CHUNK, k)
            chunk = frames[k:k + BATCH_CHUNK]
            batch = tracker.batch(tracker.prepare(chunk), frame_rows, raw=chunk if frames.ndim == 3 else None)
        if not repeated[k]:
            solution, ok, locked[k] = state.advance(tracker, batch, k % BATCH_CHUNK, reference[k])
            out["chi2"][k], rejected[k] = solution.chi2, solution.rejected_px
            transient[k] = solution.transient_px
            texture_px[k] = state.texture.corrected_px if state.texture is not None else 0
            if math.isfinite(solution.focus_sigma):
                out["focus"][k], out["focus_sigma"][k] = solution.focus, solution.focus_sigma
        else:
            state.repeat()
            ok = False
        if ok:
            out["x"][k], out["rms"][k], out["info"][k] = solution.x_mm, solution.rms_gray, solution.information
            out["gain"][k], out["offset"][k] = solution.gain, solution.offset_gray
            iterations[k] = solution.iterations
        if progress and k % report_every == 0:
            progress(k / n_frames, f"frame {k}/{n_frames}")
    if n_frames:
        _judge(state, repeated, stale, stale_reason, (n_frames - 1) // BATCH_CHUNK * BATCH_CHUNK, n_frames)
    if progress:
        progress(1.0, f"{n_frames} frames, {len(state.events)} lock event(s)")
    crlb = stream_bound_factor(model.info) / np.sqrt(np.where(out["info"] > 0, out["info"], np.nan))
    return TrackResult(out["x"], locked, out["rms"], crlb, iterations, out["gain"], out["offset"], state.events,
                       out["chi2"], rejected, stale, tracker.chi2_calibration, repeated, stale_reason, transient,
                       out["focus"], out["focus_sigma"], texture_px,
                       state.texture.summary() if state.texture is not None else None)


def _judge(state: SequentialState, repeated: np.ndarray, stale: np.ndarray, stale_reason: np.ndarray,
           start: int, stop: int) -> None:
    """The validity monitor's verdicts on frames ``start:stop`` (one chunk, solved, its batch still
    at hand) into ``stale`` and ``stale_reason``: a repeated image, shown to no watch, keeps the
    verdict of the frame before it, as in live tracking."""
    reasons = state.verdicts()
    shown = ~repeated[start:stop]
    chunk = stale_reason[start:stop]  # a view: written in place
    chunk[shown] = [reason or "" for reason in reasons]
    if not shown.all():  # a repeated image keeps the verdict of the frame before it
        before = stale_reason[start - 1] if start else ""
        last = np.maximum.accumulate(np.where(shown, np.arange(stop - start), -1))[~shown]
        chunk[~shown] = np.where(last >= 0, chunk[np.maximum(last, 0)], before)
    stale[start:stop] = stale_reason[start:stop] != ""


@dataclass
class LiveFix:
    """One frame's answer in live tracking (the daemon's position stream): its record. A field named
    in core/frame_record.py is the quantity declared there (``crlb_mm`` is ``crlb_um`` in the solver's
    unit); NaN stands for null (``x_mm`` of a frame not placed), None for no stale reason."""

    x_mm: float
    locked: bool
    rms_gray: float
    crlb_mm: float
    event: LockEvent | None
    chi2: float = float("nan")
    rejected_px: int = 0
    gain: float = 1.0
    offset_gray: float = 0.0
    stale: bool = False
    stale_reason: str | None = None
    transient_px: int = 0
    focus_px2: float = float("nan")
    focus_sigma_px2: float = float("nan")
    iterations: int = 0
    texture_px: int = 0


class LiveTracker:
    """Frame-by-frame tracking for a running rig: the same solver and lock logic as :func:`track`,
    with the light re-solved when it changes, bad pixels set aside and marks that land on the print
    learned (core/texture.py; all on by default)."""

    def __init__(self, model: FourierModel, x0_mm: float | None = None, light: str = "auto", robust: bool = True,
                 learn: bool = True, watches: Sequence[Watch] = (), texture: dict | None = None):
        """``texture``: marks learned on the print by an earlier tracker of this model (Texture.state),
        kept with the model of record: learning goes on from them (ValueError: another model's)."""
        self.model = model
        self.tracker = Tracker(model, light=light, robust=robust)
        # what it learns on the print lives as long as this tracker: a model installed anew starts without it
        learned = None if not learn else Texture(model, MAX_REJECTED_FRACTION) if texture is None else \
            Texture.from_state(model, texture, MAX_REJECTED_FRACTION)
        self.state = SequentialState(x_prev=x0_mm, texture=learned, stretch=stretch_follow(watches))
        # The validity monitor now, not at the first frame: its tables (the bound over the stroke:
        # the model at a few hundred positions, ~50 ms on a 16-row model) are model install's work.
        # ``watches``: the owner's (the daemon's scale watch with its trim), in place of the defaults.
        self.state.monitor = monitor_for(self.tracker, watches)
        self._bound_factor = stream_bound_factor(model.info)  # a JPEG stream's quantisation widens every bound
        # The lean path: a frame (a strip's row mean for a one-row model) is read into one
        # preallocated line, masked pixels zeroed as prepare does, and one batch is reloaded in
        # place; weights that follow the signal are the frame's own and go through prepare. (A
        # 16 × 100 model's frame: prepare and a batch built anew cost 30 µs of its 146.)
        self._lean = not self.tracker.signal_dependent
        self._line = np.empty((1, model.n_rows * model.n_pixels))
        self._seen = None if model.pixel_weight is None else np.asarray(model.seen(), dtype=np.float64).reshape(1, -1)
        self._batches: dict[int, TrigPolyBatch | GeneralBatch] = {}  # by rows averaged
        self._last_frame: np.ndarray | None = None  # to tell a driver's repeated image from a new one

    @property
    def stale(self) -> bool:
        """The model has stopped describing the images (sustained χ² rise): recalibrate."""
        return self.state.stale

    @property
    def texture(self) -> Texture | None:
        """What this tracker learned on the print (None: not learning)."""
        return self.state.texture

    def restart_at(self, x_mm: float) -> None:
        """The next frame is solved from ``x_mm`` (the grating's reading when a model is switched in)."""
        self.state.x_prev = x_mm

    def update(self, frame: np.ndarray, reference_mm: float = float("nan"), t: float | None = None) -> LiveFix:
        """Solve one frame ``(n,)`` or ``(R, n)``; ``reference_mm`` is the grating at that instant, if read
        (``t``, its mid-exposure, is the estimator's: this solver places each frame on its own)."""
        frame = np.asarray(frame)
        last = self._last_frame
        same = last is not None and last.shape == frame.shape and _identical(last, frame)
        if last is None or last.shape != frame.shape or last.dtype != frame.dtype:
            self._last_frame = frame.copy()
        elif not same:
            np.copyto(last, frame)  # the kept image, refreshed in place
        if same and repeats.repeated(frame[None], self.model.noise_gray or 0.0, last)[0]:
            self.state.repeat()
            return LiveFix(float("nan"), False, float("nan"), float("nan"), self.state.events[-1],
                           stale=self.state.stale, stale_reason=self.state.stale_reason)
        rows = 1 if frame.ndim == 1 else frame.shape[0]
        self.state.rows_averaged = self.model.rows_averaged(rows)
        batch = self._lean_batch(frame, rows)
        if batch is None:
            batch = self.tracker.batch(self.tracker.prepare(frame.reshape((1,) + frame.shape)), rows,
                                       raw=frame[None] if frame.ndim == 2 else None)
        elif rows > 1 and self.model.n_rows == 1:
            batch.raw = frame[None]  # a transient on a few rows of the mean is set aside on those rows only
        events_before = len(self.state.events)
        solution, ok, locked = self.state.advance(self.tracker, batch, 0, float(reference_mm))
        event = self.state.events[-1] if len(self.state.events) > events_before else None
        crlb = self._bound_factor / math.sqrt(solution.information) if solution.information > 0 else float("nan")
        return LiveFix(solution.x_mm if ok else float("nan"), locked, solution.rms_gray, crlb, event,
                       solution.chi2, solution.rejected_px, solution.gain, solution.offset_gray, self.state.stale,
                       self.state.stale_reason, solution.transient_px,
                       solution.focus if math.isfinite(solution.focus_sigma) else float("nan"), solution.focus_sigma,
                       solution.iterations if ok else 0,
                       self.state.texture.corrected_px if self.state.texture is not None else 0)

    def _lean_batch(self, frame: np.ndarray, rows: int) -> TrigPolyBatch | GeneralBatch | None:
        """The frame's batch by one reduction into the preallocated line (None: not this path)."""
        model = self.model
        if not self._lean or frame.shape[-1] != model.n_pixels or frame.ndim not in (1, 2):
            return None
        if self.tracker.clipped_rows(frame):
            return None  # a row at the sensor's limits: the general route sets its column aside
        line = self._line
        if model.n_rows > 1:
            if frame.ndim != 2 or frame.shape[0] != model.n_rows:
                return None  # prepare says what is wrong with it
            np.copyto(line.reshape(frame.shape), frame)
        elif frame.ndim == 1:
            line[0] = frame
        else:
            np.add.reduce(frame, axis=0, dtype=np.float64, out=line[0])  # the row mean, as prepare's
            np.true_divide(line, rows, out=line)
        if self._seen is not None:
            np.multiply(line, self._seen, out=line)
        limits = self.tracker.sensor_range
        if limits is not None and not self.tracker.inside_range(line).all():
            return None  # samples at the sensor's limits: the general route sets them aside
        batch = self._batches.get(rows)
        if batch is None:
            batch = self._batches[rows] = self.tracker.batch(line.reshape(1, model.n_rows, -1).copy(), rows)
        return batch.reload(line)


def _identical(kept: np.ndarray, frame: np.ndarray) -> bool:
    """Bit for bit the same image (a driver that handed the last frame again)? Sixteen samples
    spread over the frame tell a new image at once (noise moves every one; the first few alone can
    sit on a dark or clipped border and match every time); only the rare match is compared whole.
    Compared as bytes: two numpy reductions cost a live 16-row frame 4.6 µs, this 0.6 µs."""
    flat_kept, flat_new = kept.reshape(-1), frame.reshape(-1)
    stride = max(flat_kept.size // 16, 1)
    if flat_kept[::stride].tobytes() != flat_new[::stride].tobytes():
        return False
    return bool((kept == frame).all())


def _rival_weighed(tracker: Tracker, batch: GeneralBatch | TrigPolyBatch, k: int, state: SequentialState,
                   solution: FrameSolution, reference: float) -> FrameSolution:
    """The frame's answer with the acquisition's rival period weighed (core/period_rival.py): marked
    a guess while neither leads; the rival's, solved as any frame, once it has won."""
    rival = state.rival
    if rival is None:
        return solution
    verdict = rival.weigh(batch, k, solution, tracker.settings)
    if verdict is None:
        solution.period_guess = True
        return solution
    state.rival = None
    if verdict == "chosen":
        return solution
    moved = tracker.solve(batch, k, solution.x_mm + rival.offset_mm, state.memory, reference)
    state.events.append(LockEvent(state.frame, rival.describe(), solution.x_mm, moved.x_mm, True))
    return moved


def _solve_frame(tracker: Tracker, batch: GeneralBatch | TrigPolyBatch, k: int, state: SequentialState,
                 reference: float) -> tuple[FrameSolution, bool]:
    """Batch frame ``k`` as the state's next frame: continue from its last position; on any sign
    of lost lock, re-acquire and log it."""
    x_prev, events, frame, memory = state.x_prev, state.events, state.frame, state.memory
    if x_prev is None or not math.isfinite(x_prev):
        lo, hi = tracker.model.stroke_range_mm
        if math.isfinite(reference):
            solution = tracker.acquire_near(batch, k, reference, memory)
        else:
            solution, rival = tracker.acquire_with_rival(batch, k, lo, max(hi, lo + tracker.model.period_mm), memory)
            if rival is not None and tracker.untrusted(solution) is None:
                events.append(LockEvent(frame, f"acquired without a reference, but a position {rival:+.3f} mm away "
                                               "fits as well: the period is a guess",
                                        float("nan"), solution.x_mm, True))
                state.rival = PeriodRival.opened(rival, solution, tracker.model, AMBIGUITY_CHI2)
                solution.period_guess = state.rival is not None
        ok = tracker.untrusted(solution) is None
        if frame > 0 or not ok:
            events.append(LockEvent(frame, "acquisition", float("nan"), solution.x_mm if ok else float("nan"), ok))
        return solution, ok
    solution = tracker.solve(batch, k, x_prev + state.velocity, memory, reference)
    reason = tracker.lost_reason(solution, x_prev, reference)
    if reason is None:
        return _rival_weighed(tracker, batch, k, state, solution, reference), True
    anchor = reference if math.isfinite(reference) else x_prev
    again = tracker.acquire_near(batch, k, anchor, memory)
    ok = tracker.untrusted(again) is None and (
        not math.isfinite(reference) or abs(again.x_mm - reference) <= tracker.quarter_period_mm
    )
    events.append(LockEvent(frame, reason, x_prev, again.x_mm if ok else float("nan"), ok))
    return again, ok
