"""What the nuisances cost: the frame's bound against the calibration's at the same position.

A per-frame nuisance (the light, a light field, a focus term, samples set aside) can absorb a
change so well that χ² stays at its calibration level, while the frame carries less information
about x than the calibrated model would give it there: that loss is the price of the nuisance and
the evidence χ² cannot see. Information lost only to a uniform dimming of the light is the
light's own (the signal is smaller) and is left to the light watch; beyond that, a sustained loss
to less than half (a bound √2 worse) is flagged, blamed on the nuisance that was working. Only
while χ² is at its calibration level: once χ² sees the change, the χ² watch, which reads the
residual's shape, is the better judge of its cause.
"""

from __future__ import annotations

import math

import numpy as np

from graytrack.core import frame_kernel
from graytrack.core.frame_tables import FrameTables
from graytrack.core.kernels import TableEvaluator
from graytrack.core.validity import FrameSign, running

WINDOW = 100  # frames
KEPT_LIMIT = 0.5  # information kept, averaged over the window, below which the model is stale
SUSPECT = 0.8  # above this the nuisances cost little: which one works is not followed
GRID_PER_PERIOD = 64
BLAMED = ("transients", "pixels", "focus", "light")  # the nuisances a loss is blamed on, in this order


class BoundWatch:
    family = "light"
    reads = ("placed", "information", "x_mm", "rows_averaged", "gain", "free_light", "transient_px", "rejected_px",
             "focus", "field", "chi2_suspect")

    def __init__(self, grid_start: float, grid_step: float, information: np.ndarray):
        self.start, self.grid_step, self.table = grid_start, grid_step, information.tolist()
        self.kept: float | None = None
        self.blame: dict[str, float] = {}
        self._array: np.ndarray | None = None  # the table as the compiled loop reads it

    def calibrated(self, x_mm: float) -> float:
        """Information per model row on x at ``x_mm`` with the calibrated light and every sample."""
        position = (x_mm - self.start) / self.grid_step
        index = min(max(int(position), 0), len(self.table) - 2)
        fraction = min(max(position - index, 0.0), 1.0)
        return self.table[index] + fraction * (self.table[index + 1] - self.table[index])

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.information, sign.x_mm, sign.rows_averaged, sign.gain, sign.free_light,
                         sign.transient_px, sign.rejected_px, sign.focus, sign.field, sign.chi2_suspect)

    def step(self, placed: bool, information: float, x_mm: float, rows_averaged: int, gain: float, free_light: bool,
             transient_px: int, rejected_px: int, focus: float, field: bool, chi2_suspect: bool) -> str | None:
        if not (placed and math.isfinite(information) and math.isfinite(x_mm)):
            return None
        reference = self.calibrated(x_mm) * rows_averaged
        if reference <= 0:
            return None
        light = gain * gain if free_light else 1.0
        kept = min(information / (reference * light), 2.0)
        self.kept = running(self.kept, kept, WINDOW)
        if self.kept > SUSPECT:  # the common case: nothing to blame, nothing to track
            if self.blame:
                self.blame.clear()
            return None
        for family, working in zip(BLAMED, (transient_px > 0, rejected_px > 0, focus != 0.0, free_light or field)):
            self.blame[family] = running(self.blame.get(family), float(working), WINDOW)
        if self.kept >= KEPT_LIMIT or chi2_suspect:
            return None  # holding; or χ² sees the change itself, and its watch reads the residual's shape
        family, share = max(self.blame.items(), key=lambda item: item[1])
        return family if share > 0.1 else "geometry"

    def step_many(self, columns, n: int) -> list[str | None] | None:
        """:meth:`step` of ``n`` frames at once (compiled: core/watches/_kernels.py)."""
        from graytrack.core.watches import _kernels

        if not _kernels.COMPILED:
            return None
        if self._array is None:
            self._array = np.asarray(self.table, dtype=np.float64)
        known = bool(self.blame)
        state = np.array([self.kept is not None, self.kept or 0.0, known], dtype=np.float64)
        blame = np.array([self.blame[family] for family in BLAMED] if known else [0.0] * len(BLAMED))
        out = np.empty(n, dtype=np.int64)
        _kernels._bound_run(state, blame, self._array, self.start, self.grid_step, columns.array("placed", bool),
                            columns.array("information", np.float64), columns.array("x_mm", np.float64),
                            columns.array("rows_averaged", np.float64), columns.array("gain", np.float64),
                            columns.array("free_light", bool), columns.array("transient_px", np.int64),
                            columns.array("rejected_px", np.int64), columns.array("focus", np.float64),
                            columns.array("field", bool), columns.array("chi2_suspect", bool), WINDOW, SUSPECT,
                            KEPT_LIMIT, out)
        self.kept = float(state[1]) if state[0] else None
        self.blame = dict(zip(BLAMED, blame.tolist())) if state[2] else {}
        if not (out >= 0).any():
            return [None] * n
        return np.array((*BLAMED, "geometry", None), dtype=object)[out].tolist()


def calibrated_information(model) -> tuple[float, float, np.ndarray] | None:
    """The information per model row on x with the calibrated light and every sample, on a grid over the
    stroke: (grid start, grid step, values); None when the model has no stroke range. From the model
    alone, weighed as its tracker weighs each sample (core/tracking.py), so that a watch made before its
    tracker (an owner's scale watch, carrying the far-off judgement) judges against the same figure. Made
    once a model (every tracker of it has a bound and a far-off watch, and the closed loop tracks each of
    its models on several runs); the values are read-only."""
    return model.derived("calibrated_information", lambda: _calibrated_information(model))


def _calibrated_information(model) -> tuple[float, float, np.ndarray] | None:
    lo, hi = model.stroke_range_mm
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    step = model.period_mm / GRID_PER_PERIOD
    grid = np.arange(lo - model.period_mm, hi + model.period_mm + step, step)
    values, slopes = TableEvaluator(FrameTables.of(model)).evaluate(grid)
    if model.noise().signal_dependent:  # the model's inverse variance at each grid position, in one compiled pass
        pixel_weight = np.ones(model.n_rows * model.n_pixels) if model.pixel_weight is None else \
            np.ascontiguousarray(model.pixel_weight, dtype=np.float64).reshape(-1)
        weights, _ = frame_kernel.sample_weights(values, model.pixel_noise, pixel_weight, 1.0, None)
    else:
        weights = model.inverse_variance(np.zeros((model.n_rows, model.n_pixels))).reshape(1, -1)
    information = np.sum(weights * slopes * slopes, axis=1)
    information.flags.writeable = False
    return float(grid[0]), step, information


def make(tracker) -> BoundWatch | None:
    table = calibrated_information(tracker.model)
    return None if table is None else BoundWatch(*table)
