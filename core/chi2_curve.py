"""The calibration's χ² level along the stroke: what a frame's χ² is held against where it was taken.

A model that is right to well within the noise still leaves a misfit that depends on where the
target is seen (a print detail it does not carry, the light's gradient meeting the print): on the
lab strip the frames' χ² runs from 3 % below to 3.5 % above its mean as the stage crosses the
stroke, slowly, so that over a hundred frames its running average wanders six times as far as
the noise alone would take it. Held against one level, that wander read as a change of the images
on a quarter of the frames of a normal run: the light field and the focus were solved, and the
residual explained, on every one of them, for nothing, and a real change of a few per cent could
hide in the wander.

Calibration tracks its own recording as tracking will (core/calibration_line.py); the frames'
χ², binned along x, gives the level relative to its mean at each place, kept when its variation
stands clear of what the bins' own noise makes (else the level is one everywhere). Tracking
divides each frame's χ² by the level where the frame was placed before it watches the running
average: what is left is the noise, and a change.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

CURVE_BINS = 32  # stretches of the stroke at most
MIN_FRAMES_PER_BIN = 20  # calibration frames per stretch at least (a bin's mean to ~7 % of the spread)
# the bins' means must vary this many times more than their own noise makes them (variance ratio)
# for the level to be kept: below, a flat level is the better guess
SIGNIFICANCE = 3.0
LEVEL_RANGE = (0.5, 2.0)  # a level outside this is no misfit of a calibrated model: clipped


@dataclass(frozen=True)
class Chi2Curve:
    """The relative χ² level (mean 1) at the centres of stretches of the stroke; linear between
    them, the end values beyond."""

    x_mm: tuple[float, ...]
    level: tuple[float, ...]

    def at(self, x_mm: float) -> float:
        """The level at ``x_mm`` (one scalar: this runs for every frame, so plain Python)."""
        centres, level = self.x_mm, self.level
        i = bisect_right(centres, x_mm)
        if i == 0:
            return level[0]
        if i == len(centres):
            return level[-1]
        x0, x1 = centres[i - 1], centres[i]
        share = (x_mm - x0) / (x1 - x0) if x1 > x0 else 0.0
        return level[i - 1] + share * (level[i] - level[i - 1])

    def anywhere(self, x_mm: float, period_mm: float) -> float:
        """The highest level at the places whole periods ``period_mm`` from ``x_mm`` along the curve: a
        frame of a model that repeats once a period, placed without a grating, is at one of them, its
        origin picked by noise (core/stroke_place.py). Read at the place it was given, a JPEG strip's
        level (0.85-1.16 along the stroke) was read a period away, 7-25 % low: its run's χ² average
        stood above the limit on 21 % of a steady run (flagged `geometry`) and suspected a blur on 309
        frames. Held against the highest, a change still shows above every place the frame may be."""
        first, last = self.x_mm[0], self.x_mm[-1]
        if not period_mm > 0.0:
            return self.at(x_mm)
        place = first + (x_mm - first) % period_mm
        best = self.at(place)
        while (place := place + period_mm) <= last:
            best = max(best, self.at(place))
        return best

    def as_dict(self) -> dict[str, list[float]]:
        return {"x_mm": [round(v, 6) for v in self.x_mm], "level": [round(v, 4) for v in self.level]}

    @classmethod
    def from_info(cls, info: dict) -> "Chi2Curve | None":
        """The curve a model's info keeps (``calibration_chi2_curve``), or None (a flat level)."""
        body = info.get("calibration_chi2_curve")
        if not isinstance(body, dict):
            return None
        x_mm, level = body.get("x_mm"), body.get("level")
        if not isinstance(x_mm, list) or not isinstance(level, list) or len(x_mm) != len(level) or len(x_mm) < 2:
            return None
        x_mm, level = [float(v) for v in x_mm], [float(v) for v in level]
        if any(b < a for a, b in zip(x_mm, x_mm[1:])) or not all(np.isfinite(x_mm + level)):
            return None
        low, high = LEVEL_RANGE
        return cls(tuple(x_mm), tuple(min(max(v, low), high) for v in level))


def frame_spread(x_mm: np.ndarray, chi2: np.ndarray, curve: Chi2Curve | None, samples: float) -> float:
    """How much wider than white noise's in ``samples`` samples (√(2/samples) of the level) one frame's χ² scatters
    from the next's, at least 1: the share of the noise the samples do not draw independently (a row's offset
    drawn each frame is one draw for a whole row, a pixel flickering between two levels one for a pixel). A
    frame's test counts its samples as ``samples / spread²`` independent ones.

    Measured on the frames in their order along the stroke, from each one's difference with the next (half the
    mean square): what varies with the place the frames see (a misfit the level along the stroke, ``curve``, is
    too coarse to hold: a smudge the model could not take in) is nearly the same for neighbours a few µm apart and
    drops out, where noise drawn each frame does not. Kept where it stands clear of its own sampling noise
    (:data:`SIGNIFICANCE` of a variance ratio's over as many differences), else 1."""
    usable = np.isfinite(x_mm) & np.isfinite(chi2) & (chi2 > 0.0)
    if usable.sum() < MIN_FRAMES_PER_BIN or samples < 1.0:
        return 1.0
    x, values = np.asarray(x_mm, dtype=np.float64)[usable], np.asarray(chi2, dtype=np.float64)[usable]
    level = np.ones_like(x) if curve is None else np.array([curve.at(float(place)) for place in x])
    # (in logarithms: a χ²'s scatter is relative to its level, which a misfit raises where it is)
    logs = np.log(values / level)[np.argsort(x, kind="stable")]
    ratio = 0.5 * float(np.mean(np.diff(logs) ** 2)) / (2.0 / samples)  # the variance over white noise's
    if ratio - 1.0 <= SIGNIFICANCE * math.sqrt(2.0 / (logs.size - 1)):
        return 1.0
    return math.sqrt(ratio)


def measured(x_mm: np.ndarray, chi2: np.ndarray) -> Chi2Curve | None:
    """The level along x from frames at ``x_mm`` with χ² ``chi2`` (per used sample), or None when
    the frames are too few or the level's variation does not stand out of the bins' noise.
    Each bin's departure from the mean is shrunk by its noise share (the bins' noise would
    otherwise be built into every later frame's level)."""
    usable = np.isfinite(x_mm) & np.isfinite(chi2) & (chi2 > 0.0)
    x, values = np.asarray(x_mm, dtype=np.float64)[usable], np.asarray(chi2, dtype=np.float64)[usable]
    n_bins = min(CURVE_BINS, x.size // MIN_FRAMES_PER_BIN)
    if n_bins < 2:
        return None
    order = np.argsort(x, kind="stable")
    x, relative = x[order], values[order] / values.mean()
    bins = np.array_split(np.arange(x.size), n_bins)  # equal numbers of frames: a sweep's speed does not matter
    means = np.array([relative[b].mean() for b in bins])
    noise = np.array([relative[b].var(ddof=1) / b.size for b in bins])  # each mean's variance from its own scatter
    between = float(np.mean((means - 1.0) ** 2))
    expected = float(noise.mean())
    if between <= SIGNIFICANCE * expected:
        return None
    level = 1.0 + (means - 1.0) * (1.0 - expected / between)
    centres = np.array([x[b].mean() for b in bins])
    low, high = LEVEL_RANGE
    return Chi2Curve(tuple(centres.tolist()), tuple(np.clip(level, low, high).tolist()))
