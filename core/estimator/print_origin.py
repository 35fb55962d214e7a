"""Without the grating, which whole period of the print the run is at, told by the marks its calibration learned.

A model that repeats once a period places a frame from the image alone up to whole periods: the acquisition picks
the origin (filter.py ``_places``). The print's own marks do not repeat: calibration's sweep learned them at
their place along the print (filter.py ``calibration_print_map``), and a run that knew its period would start from
them as a run with the grating does, instead of learning them again. So the marks are held aside, and each frame the
estimate vouches for weighs them at each place the frame may be (a whole number of periods on either way): the
log-likelihood ratio of its samples with the marks there against without (each sample seeing a mark as the
print's map weighs its own evidence, print_map.py ``learn``). A place whose marks the frames speak for by one
sample's test at the false-alarm rate (the map's ``confirm``) beyond every other place and beyond none is the
run's; the map is then restored there, and the run's places are that one. A place the frames never saw a mark at
weighs nothing: a run that never passes one stays undecided, as before.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from graytrack.core import kernels
from graytrack.core.estimator.print_map import PrintMap


def evidence(y: np.ndarray, h: np.ndarray, noise_var: np.ndarray, mask: np.ndarray, level: float, xi: float,
             stretch: float, target: np.ndarray, centred: np.ndarray, rows_of: np.ndarray, origin: float, step: float,
             nodes: int, f: np.ndarray, s: np.ndarray, learned: np.ndarray) -> float:
    """The log-likelihood ratio of the frame's samples ``y`` (the model's value ``h``, the noise's variance, the
    weights ``mask``, the calibration's χ² ``level``) with the learned marks of the map read at ``origin`` against
    without: each sample that sees a learned node, its change carried to the sample by its slope, weighs the
    residual with the change (and its variance) against the residual without."""
    total = 0.0
    for p in range(y.size):
        if mask[p] <= 0.0:
            continue
        u = (xi + target[p] + stretch * centred[p] - origin) / step
        k = math.floor(u + 0.5)
        if k < 1 or k >= nodes - 1:
            continue
        j = rows_of[p] * nodes + k
        if not learned[j]:
            continue
        a = u - k
        slope = f[j + 1] - f[j] if a >= 0.0 else f[j] - f[j - 1]
        change = f[j] + slope * a
        hp = h[p]
        var_y = noise_var[p] * level / mask[p]
        without = y[p] - hp
        with_mark = y[p] - (1.0 + change) * hp
        var_mark = var_y + hp * hp * s[j]
        total += 0.5 * (without * without / var_y - with_mark * with_mark / var_mark - math.log(var_mark / var_y))
    return total


if kernels.COMPILED:
    evidence = kernels.numba.njit(cache=True, nogil=True, error_model="numpy")(evidence)


class PrintOrigin:
    """Calibration's marks (a print map's ``state``, read into ``marks``, a map of the run's grid) weighed at each
    place a frame may be, a whole number of ``period_mm`` from where the run placed it, until one is decided
    (``decided``: the periods the print's coordinates lie ahead of the run's)."""

    def __init__(self, state: dict, marks: PrintMap, period_mm: float) -> None:
        marks.restore(state, shift_mm=0.0)  # (ValueError where the grid is not the run's: the caller's to handle)
        self.state, self.marks, self.period = state, marks, float(period_mm)
        learned = marks.learned()
        self._learned = np.ascontiguousarray(learned)
        self._places = np.sort(marks.place_mm(np.flatnonzero(learned)))
        self._reach = (float(marks.target.min()), float(marks.target.max()))  # the field along the print
        self.evidence: dict[int, float] = {}
        self.decided: int | None = None

    def reset(self) -> None:
        """Nothing weighed (a run placed afresh from the image: its period is the acquisition's pick again)."""
        self.evidence = {}
        self.decided = None

    @property
    def any(self) -> bool:
        """Whether calibration learned a mark to tell the place by."""
        return self._places.size > 0

    def in_view(self, xi: float, periods: int) -> bool:
        """Whether a learned mark lies in the field of an image at ``xi`` read ``periods`` ahead."""
        lo = xi + self._reach[0] + periods * self.period - self.marks.step
        hi = xi + self._reach[1] + periods * self.period + self.marks.step
        first = bisect.bisect_left(self._places, lo)
        return first < self._places.size and self._places[first] <= hi

    def observe(self, y: np.ndarray, h: np.ndarray, noise_var: np.ndarray, mask: np.ndarray, level: float,
                xi: float, stretch: float, candidates: list[int]) -> int | None:
        """One vouched frame's evidence at each of ``candidates`` (periods ahead) whose field holds a mark; returns
        the place decided by it (None while undecided)."""
        if self.decided is not None:
            return self.decided
        marks = self.marks
        for periods in candidates:
            if not self.in_view(xi, periods):
                continue
            origin = marks.base_origin - periods * self.period
            self.evidence[periods] = self.evidence.get(periods, 0.0) + evidence(
                y, h, noise_var, mask, level, xi, stretch, marks.target, marks.centred, marks.rows_of, origin,
                marks.step, marks.nodes, marks.f, marks.s, self._learned)
        if self.evidence:
            ranked = sorted(((value, periods) for periods, value in self.evidence.items()
                             if periods in candidates), reverse=True)
            if ranked:
                best, periods = ranked[0]
                rival = max(ranked[1][0] if len(ranked) > 1 else 0.0, 0.0)
                if best - rival >= marks.confirm:
                    self.decided = periods
        return self.decided


__all__ = ["PrintOrigin", "evidence"]
