"""The camera against the grating, frame by frame: when both are read, their difference is the
error the instrument makes, whatever the images look like. A model can fit every frame (χ² at its
calibration level, the light re-solved each frame) and still place them tens of bounds off, when
calibration absorbed something the run does not repeat (a camera's gain hunting during the sweep
bent the model). The scale watch follows a drift that is a line along the stroke; this one the
scatter: the windowed spread of camera − grating beyond ``LIMIT`` times the frames' own bound.
It says nothing of the cause: it blames ``geometry`` (the model does not describe the rig), and a
watch that reads the cause in the images names a more specific family over it.

Its window holds the frames the images cannot judge (as the bound watch's, only while χ² is at
its calibration level): a frame while the running χ² is suspect, or one beyond the gate whose own
χ² is beyond three of its spreads, is one the images already say the model does not describe; it
is held against the gate (flagged when beyond) without entering the window. Taken in, a cable's
shadow across the field (40 frames hundreds of µm off, clipped at the gate, or inside it with a
light field's sevenfold bound) lifted the spread for the 300 frames after it, each flagged though
at its bound.
"""

from __future__ import annotations

import math

from graytrack.core.compression import stream_bound_factor
from graytrack.core.reference_monitor import GATE
from graytrack.core.validity import FrameSign, running

WINDOW = 200  # frames: the spread's relative noise is √(2/200) = 10 %, its ratio's 5 %
LIMIT = 2.2  # spread over bound beyond which the run is off (the 2× of the acceptance, plus that noise)
SETTLE = 30  # frames with a grating reading before the spread is trusted (at 1.3x a run is then still far below LIMIT)
# A difference beyond GATE of its σ (the window's spread, at least the frames' bound, and the frame's own)
# flags its own frame and enters the window clipped to the gate: one reading gone wrong (the grating's
# or the camera's) then lifts the spread by a few per cent, where a single grating reading 0.5 mm off
# entered unclipped lifts it for 156 frames and flags every one; a difference that stays beyond moves the window
# a gate's worth a frame, each of those frames flagged on its own.
GATE2 = GATE * GATE


class GratingWatch:
    family = "geometry"
    reads = ("placed", "reference_mm", "x_mm", "information", "chi2", "chi2_suspect")

    def __init__(self, bound_scale2: float = 1.0, chi2_limit: float = math.inf) -> None:
        self.bound_scale2 = bound_scale2  # the frames' variance over the sensor's (a JPEG stream's quantisation)
        self.chi2_limit = chi2_limit  # a frame beyond the gate with its own χ² beyond this: the images' (above)
        self.mean: float | None = None  # camera − grating, mm
        self.square: float | None = None
        self.bound2: float | None = None  # the frames' Cramér–Rao variance, mm²
        self.count = 0

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.reference_mm, sign.x_mm, sign.information, sign.chi2, sign.chi2_suspect)

    def step(self, placed: bool, reference_mm: float, x_mm: float, information: float, chi2: float = 0.0,
             chi2_suspect: bool = False) -> str | None:
        if placed and math.isfinite(reference_mm) and math.isfinite(x_mm) and information > 0:
            difference, beyond = self._gated(x_mm - reference_mm, self.bound_scale2 / information)
            if chi2_suspect or (beyond and chi2 > self.chi2_limit):  # the images judge this frame
                return self.family if beyond else self._verdict()
            self.count += 1
            # a plain mean until the window is full, then the running one: the first readings do not
            # outweigh the next hundred
            window = min(self.count, WINDOW)
            self.mean = running(self.mean, difference, window)
            self.square = running(self.square, difference * difference, window)
            self.bound2 = running(self.bound2, self.bound_scale2 / information, window)
            if beyond:
                return self.family
        return self._verdict()

    def _verdict(self) -> str | None:
        """The window's own verdict: its spread beyond LIMIT times the frames' bound."""
        mean, square, bound2 = self.mean, self.square, self.bound2  # (None together, before a first reading)
        if self.count < SETTLE or mean is None or square is None or not bound2:
            return None
        spread2 = max(square - mean * mean, 0.0)
        if spread2 <= LIMIT * LIMIT * bound2:
            return None
        return self.family

    def _gated(self, difference: float, frame_bound2: float) -> tuple[float, bool]:
        """(the difference as the window takes it, whether it was beyond the gate)."""
        mean, square, bound2 = self.mean, self.square, self.bound2
        if self.count < SETTLE or mean is None or square is None or not bound2:
            return difference, False
        spread2 = max(square - mean * mean, 0.0)
        deviation = difference - mean
        gate2 = GATE2 * (max(spread2, bound2) + frame_bound2)
        if deviation * deviation <= gate2:
            return difference, False
        return mean + (math.sqrt(gate2) if deviation > 0 else -math.sqrt(gate2)), True

    def step_many(self, columns, n: int) -> list[str | None] | None:
        """:meth:`step` of ``n`` frames at once (compiled: core/watches/_kernels.py)."""
        import numpy as np

        from graytrack.core.watches import _kernels

        if not _kernels.COMPILED:
            return None
        state = np.array([self.mean or 0.0, self.square or 0.0, self.bound2 or 0.0, self.count], dtype=np.float64)
        has = np.array([self.mean is not None, self.square is not None, self.bound2 is not None])
        out = np.zeros(n, dtype=bool)
        _kernels._grating_run(state, has, columns.array("placed", bool), columns.array("reference_mm", np.float64),
                              columns.array("x_mm", np.float64), columns.array("information", np.float64),
                              columns.array("chi2", np.float64), columns.array("chi2_suspect", bool), self.chi2_limit,
                              self.bound_scale2, WINDOW, SETTLE, LIMIT * LIMIT, GATE2, out)
        values = state.tolist()
        self.mean, self.square, self.bound2 = (value if known else None for value, known in zip(values, has.tolist()))
        self.count = int(values[3])
        if not out.any():
            return [None] * n
        return [self.family if flagged else None for flagged in out.tolist()]


def for_model(model, chi2_calibration: float, chi2_curve) -> GratingWatch:
    """For a model whose calibration left χ² at ``chi2_calibration`` (``chi2_curve``: its level along
    the stroke, None when flat)."""
    # a model whose χ² level varies along the stroke holds each frame against its own level, not this watch
    spread = math.sqrt(2.0 / (model.n_rows * model.n_pixels))
    limit = chi2_calibration * (1.0 + 3.0 * spread) if chi2_curve is None else math.inf
    return GratingWatch(stream_bound_factor(model.info) ** 2, limit)


def make(tracker) -> GratingWatch:
    return for_model(tracker.model, tracker.chi2_calibration, tracker.chi2_curve)
