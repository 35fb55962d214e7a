"""What the stage was commanded to do: its phases of acceleration, as its owner knows them.

A stage follows a planned path: it accelerates only where its controller was told to (a move's ramps,
a stop) and, between those phases, holds its speed or rests within its servo's ripple. A recording
states the phases it was given (core/recording.py ``STAGE_PHASES``: start s, end s, |a| mm/s²); a
running rig hands them over as it issues them. Both the motion's process noise (filter.py: the path
bends by what its command asked, elsewhere barely) and the mount's test (mount.py: a step no
commanded motion makes) read them here.
"""

from __future__ import annotations

import bisect

import numpy as np


class StageCommands:
    """The stage's commanded phases of acceleration, each held ``settle_s`` past its end while the servo catches
    up; ``most``: the acceleration a phase given without one asks (the stage's most). ``phases`` None: the
    commands are not known (the stage may accelerate anywhere); an empty array: known, none yet."""

    def __init__(self, phases: np.ndarray | None, most: float, settle_s: float = 0.0):
        self.known = phases is not None
        self.most, self.settle_s = float(most), float(settle_s)
        given = [] if phases is None else np.asarray(phases).tolist()
        self._kept(sorted((start, end + self.settle_s, abs(asked)) for start, end, asked in given))

    def command(self, start: float, end: float, acceleration: float | None = None, since: float = -np.inf) -> None:
        """One more phase (``start``, ``end`` s in the frames' clock, |a| mm/s²; None: the stage's most), in any
        order; a phase given again with the same ``start`` replaces the one before (a motion whose end was not
        known when it began, ``end`` = inf until the stage is seen at rest, is closed that way). Phases that ended
        before ``since`` (s: the earliest interval still asked about) are dropped."""
        self.known = True
        start = float(start)
        phases = [phase for phase in zip(self.starts, self._ends, self._asked) if phase[0] != start and
                  phase[1] > since]
        asked = self.most if acceleration is None else abs(float(acceleration))
        phases.append((start, float(end) + self.settle_s, asked))
        self._kept(sorted(phases))

    def _kept(self, phases: list[tuple[float, float, float]]) -> None:
        """The phases (start, settled end, |a|) by start, and where an earlier one may still reach: the most of
        the ends so far (:meth:`asked` walks back only while it reaches the interval)."""
        self.starts = [phase[0] for phase in phases]
        self._ends = [phase[1] for phase in phases]
        self._asked = [phase[2] for phase in phases]
        self._reach = np.maximum.accumulate(self._ends).tolist() if phases else []

    def asked(self, start: float, end: float) -> float:
        """The most the stage was commanded to accelerate between ``start`` and ``end`` (s; mm/s²), by bisection
        over the phases: 0 between them, the stage's most where the commands are not known."""
        if not self.known:
            return self.most
        most = 0.0
        k = bisect.bisect_left(self.starts, end) - 1
        while k >= 0 and self._reach[k] > start:
            if self._asked[k] > most and self._ends[k] > start:
                most = self._asked[k]
            k -= 1
        return most


def commanded(t: np.ndarray, phases: np.ndarray | None, settle_s: float) -> np.ndarray | None:
    """The most the stage was commanded to accelerate in each interval between the frames at times ``t`` (mm/s²,
    ``t.size − 1`` of them): the largest of the ``phases`` (start s, end s, |a| mm/s², core/recording.py) that
    overlap it, each held ``settle_s`` past its end while the servo catches up; None without phases."""
    if phases is None:
        return None
    t = np.asarray(t, dtype=np.float64)
    out = np.zeros(max(t.size - 1, 0))
    for start, end, acceleration in phases:
        overlap = (t[1:] > start) & (t[:-1] < end + settle_s)
        np.maximum(out, np.where(overlap, acceleration, 0.0), out=out)
    return out
