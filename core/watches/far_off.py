"""The camera far off the grating: the model's scale is not this rig's.

A model whose period or pixel pitch is wrong for the rig (one calibrated on another target or
lens, installed here) still fits every frame after a fashion: the per-frame light and focus terms
bend to absorb the mismatch, so the light and focus watches fire and, being the more specific
families, would name the cause, their advice pointing the wrong way. Tracked with the paper rig's model
5 % off in period, the camera sat 357 µm (~250 bounds) off the grating at rest and 380 µm in a
sweep, and the frames were flagged ``light`` and ``focus``; 1 % off, 62-86 µm, flagged mostly
``geometry``, ``light`` and ``focus``.

Nothing a light or focus change does moves the positions by tens of bounds while the images still
fit: a camera that far from the grating, frame after frame, is the model's scale. So this watch is
decisive (it outranks what the nuisances suggest) and names ``scale``, whose advice says the
model's period or pitch does not match the rig. It judges the median of camera − grating over the
last :data:`WINDOW` frames (one grating reading gone wrong moves a median by nothing) against
:data:`FAR_BOUNDS` times the bound of the calibrated light (the model's own precision: a wrong model
makes the tracker solve a light field, whose frames' bound then rose from 2.2 to 17 µm at 1 % off),
and against the median's own noise under the frames' bound as solved, so noise is never "far".

A lens whose magnification drifts with the optical axis far off the ROI slides the image as far
(3000 ppm × 500 px on a 16-row strip: hundreds of µm), and that is no wrong model: the scale watch
(core/watches/scale.py) carries this watch beside its line, and names its verdict ``magnification``
where the line's drift is a lens's (its stretch and its scale say so), ``scale`` otherwise; decisive
either way (core/validity.py ``Decisive``).
"""

from __future__ import annotations

import math
import statistics
from collections import deque

import numpy as np

from graytrack.core.compression import stream_bound_factor
from graytrack.core.validity import FrameSign, running
from graytrack.core.watches.bound import calibrated_information

WINDOW = 20  # frames with a grating reading: the median of camera - grating over these
FAR_BOUNDS = 100.0  # |median| beyond this many calibrated bounds: further than a light or focus change moved any
NOISE_LIMIT = 6.0  # ... and beyond this many standard errors of the median (of the frames' bounds as solved)
MEDIAN_SE = math.sqrt(math.pi / 2.0 / WINDOW)  # a median's standard error over the noise's σ


class FarOffWatch:
    family = "scale"
    decisive = True
    reads = ("placed", "reference_mm", "x_mm", "information", "rows_averaged")

    def __init__(self, calibrated_information: float, bound_scale2: float = 1.0) -> None:
        self.calibrated_information = calibrated_information  # per model row, the stroke's median (1/mm²)
        self.bound_scale2 = bound_scale2  # the frames' variance over the sensor's (a JPEG stream's quantisation)
        self.differences: deque[float] = deque(maxlen=WINDOW)  # camera - grating, mm
        self.bound2: float | None = None  # running Cramér–Rao variance of the frames as solved, mm²
        self.calibrated2: float | None = None  # ... with the calibrated light and every sample

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.reference_mm, sign.x_mm, sign.information, sign.rows_averaged)

    def step(self, placed: bool, reference_mm: float, x_mm: float, information: float,
             rows_averaged: int) -> str | None:
        if placed and math.isfinite(reference_mm) and math.isfinite(x_mm) and information > 0:
            self.differences.append(x_mm - reference_mm)
            self.bound2 = running(self.bound2, self.bound_scale2 / information, WINDOW)
            calibrated = self.calibrated_information * rows_averaged
            self.calibrated2 = running(self.calibrated2, self.bound_scale2 / calibrated, WINDOW)
        if len(self.differences) < WINDOW or not self.bound2 or not self.calibrated2:
            return None
        offset2 = statistics.median(self.differences) ** 2
        far = offset2 > FAR_BOUNDS * FAR_BOUNDS * self.calibrated2
        return self.family if far and offset2 > (NOISE_LIMIT * MEDIAN_SE) ** 2 * self.bound2 else None

    def step_many(self, columns, n: int) -> list[str | None]:
        """:meth:`step` of ``n`` frames at once: the running bounds in the same order of operations,
        the medians of every window the chunk ends (numpy's median of an even window is the mean of
        its two middle values, as :func:`statistics.median`'s)."""
        keep = columns.array("placed", bool) & np.isfinite(columns.array("reference_mm", np.float64)) \
            & np.isfinite(columns.array("x_mm", np.float64)) & (columns.array("information", np.float64) > 0)
        kept = keep.tolist()
        rows = zip(kept, columns["reference_mm"], columns["x_mm"], columns["information"], columns["rows_averaged"])
        differences = list(self.differences)
        before = len(differences)
        ready: list[tuple[int, float, float] | None] = []  # per frame: (differences so far, bound², calibrated²)
        for placed, reference_mm, x_mm, information, rows_averaged in rows:
            if placed:
                differences.append(x_mm - reference_mm)
                self.bound2 = running(self.bound2, self.bound_scale2 / information, WINDOW)
                calibrated = self.calibrated_information * rows_averaged
                self.calibrated2 = running(self.calibrated2, self.bound_scale2 / calibrated, WINDOW)
            bound2, calibrated2 = self.bound2, self.calibrated2
            ready.append((len(differences), bound2, calibrated2)
                         if len(differences) >= WINDOW and bound2 and calibrated2 else None)
        self.differences.extend(differences[before:])
        if not any(ready):
            return [None] * n
        first = max(min(entry[0] for entry in ready if entry is not None) - WINDOW, 0)
        windows = np.lib.stride_tricks.sliding_window_view(np.asarray(differences[first:]), WINDOW)
        medians = np.median(windows, axis=1).tolist()  # medians[j]: the window ending at differences[first + j + W - 1]
        families: list[str | None] = []
        for entry in ready:
            if entry is None:
                families.append(None)
                continue
            count, bound2, calibrated2 = entry
            offset2 = medians[count - WINDOW - first] ** 2
            far = offset2 > FAR_BOUNDS * FAR_BOUNDS * calibrated2
            families.append(self.family if far and offset2 > (NOISE_LIMIT * MEDIAN_SE) ** 2 * bound2 else None)
        return families


def for_model(model) -> FarOffWatch | None:
    """The watch for ``model``; None when the model has no stroke range."""
    table = calibrated_information(model)
    if table is None:
        return None
    return FarOffWatch(float(np.median(table[2])), stream_bound_factor(model.info) ** 2)


def make(tracker) -> FarOffWatch | None:
    """The watch for ``tracker``'s model (validity.monitor_for) where no scale watch carries it (one that
    reads a grating does: core/watches/scale.py names a lens's slide ``magnification`` instead)."""
    return for_model(tracker.model)
