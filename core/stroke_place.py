"""Where along the calibrated stroke a frame may be, for what a calibration keeps place by place.

A calibration keeps some of what it learned stretch by stretch along the stroke (where its model
erred beyond its bound: ``calibration_error_profile``, core/watches/adequacy.py). Such knowledge
is only as good as the frame's place. Read with a grating, the tracker's position is the stage's
(the tracker re-acquires wherever it leaves the grating by a quarter period). Read without one, on
a model that repeats once a period (no layer along the stroke, no target map: core/period_rival.py
``repeats``), the acquisition's origin is one of the print's periods, picked by noise: every
position may be the frame's true one plus any whole number of periods. That costs nothing where
the model repeats, but a profile looked up there is read a period away. The seed model on the
paper rig with 3 scratches (period 8.6 mm over a 10.45 mm stroke), tracked with ``--no-reference``,
started at 8.62 mm while the stage stood at 0: the stretch there was one the calibration had at
its bound, the true one (the scratch's) 3.7× off, and frames 1-10, 4-6 bounds off, went
unflagged (5 of the run's 8 far frames).

So until a grating reading has placed the run, a frame of such a model may be at any place of its
phase within the stroke, and a stretch flagged anywhere there flags it: the profile folded onto
one period (:func:`folded`). A model that does not repeat is placed by its image (a period rival
that has not settled is flagged ``period`` meanwhile: core/watches/period.py).
"""

from __future__ import annotations

import math

import numpy as np


class StrokePlace:
    """Whether the run's frames are placed along the stroke: known from the first finite grating
    reading on (or from the start, ``period_mm`` None: a model the image places), before that only
    up to whole periods of ``period_mm``."""

    def __init__(self, period_mm: float | None) -> None:
        self.period_mm = period_mm
        self.known = period_mm is None or not period_mm > 0

    def see(self, reference_mm: float) -> bool:
        """One frame's grating reading (NaN: none); whether the frame's place is known."""
        if not self.known and math.isfinite(reference_mm):
            self.known = True
        return self.known

    def see_many(self, reference_mm: np.ndarray) -> np.ndarray:
        """:meth:`see` of each frame in order: whether each frame's place is known."""
        known = np.logical_or.accumulate(np.isfinite(reference_mm)) | self.known
        if known.size:
            self.known = bool(known[-1])
        return known


def folded(edges_mm: list[float], flagged: list[bool], period_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The flagged stretches (between consecutive ``edges_mm``) folded onto one period from the
    first edge: disjoint phase intervals ``(starts, ends)`` in mm, sorted; a phase inside one has a
    flagged stretch at some whole number of periods from it within the stroke."""
    lo = edges_mm[0]
    pieces: list[tuple[float, float]] = []
    for a, b, off in zip(edges_mm[:-1], edges_mm[1:], flagged):
        if not off:
            continue
        if b - a >= period_mm:
            return np.array([0.0]), np.array([period_mm])
        start = (a - lo) % period_mm
        end = start + (b - a)
        if end <= period_mm:
            pieces.append((start, end))
        else:  # the stretch wraps past the period's end
            pieces += [(start, period_mm), (0.0, end - period_mm)]
    merged: list[list[float]] = []
    for start, end in sorted(pieces):
        if merged and start <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], end)
        else:
            merged.append([start, end])
    return np.array([m[0] for m in merged]), np.array([m[1] for m in merged])


def in_folded(x_mm: np.ndarray | float, lo_mm: float, period_mm: float, starts: np.ndarray,
              ends: np.ndarray) -> np.ndarray:
    """Whether each position's phase (from ``lo_mm``) falls in one of the :func:`folded` intervals."""
    phase = np.mod(np.asarray(x_mm, dtype=np.float64) - lo_mm, period_mm)
    index = np.searchsorted(starts, phase, side="right") - 1
    inside = index >= 0
    return inside & (phase <= ends[np.maximum(index, 0)])
