"""What the daemon told the stage to do, as phases of acceleration on the host clock, for the estimator's mount test.

Without a grating, a step of the image against the carriage is either the stage (within what it may accelerate)
or the camera moving on its mount (core/estimator/mount.py). Knowing only the stage's most acceleration, a knock
of 40 µm hides in what a stage at 100 mm/s² may do between four frames at 50 frames/s; knowing **when** it was
told to move, a stage at rest or cruising allows only what its servo does beyond its commands (6 µm there).

The daemon is where every command to the stage passes (``[daemon] stage_commanded_here``): REST moves, jogs,
homing, velocity changes and stops (stage_control.py) and the calibration sweep's moves (sweep.py) all note
their command here before it is sent. How long the motion lasts is not planned here (the controller's profile,
its latency, a stop blending into a move): each command opens a phase at the stage's most acceleration, and
the phase closes where the stage's readings next show it at rest (:meth:`Readings.rest_after_command`: a
later instant than the arrival, never an earlier one). A poller that reads nothing leaves the phase open: the
stage's most is allowed, never less than it might have done; so does a command sent before the readings
showed the last one's rest (that phase then closes at the next rest they show).

The frame loop asks :meth:`CommandedMotion.since` each frame with the stamp it saw last and hands what changed
to its estimator (:meth:`LiveEstimator.commanded`): one comparison while nothing changed; the estimator is
touched by the frame loop only.
"""

from __future__ import annotations

import math
import threading
from collections import deque

from graytrack.core.estimator.settings import TUNABLES
from graytrack.service.daemon.grating import Readings

KEEP = 64  # phases kept for a tracker built later (a model switched in mid-move): far more than a few seconds hold


class CommandedMotion:
    """The phases of acceleration commanded of the stage: (start s, end s) on the host clock, each at the stage's
    most acceleration (the estimator's), ``end`` inf until the readings show the stage at rest again."""

    def __init__(self, readings: Readings, acceleration_mm_s2: float | None = None, keep: int = KEEP) -> None:
        self.readings = readings
        # the most the stage accelerates (its ACC/DEC, mm/s² on the host clock), asked of each phase; None: the
        # estimator's own most (core/estimator/settings.py stage_acceleration)
        self.acceleration_mm_s2 = acceleration_mm_s2
        self._lock = threading.Lock()
        self._phases: deque[list[float]] = deque(maxlen=keep)  # [start, end, stamp of its last change]
        self._stamp = 0
        self._open = False

    def note_command(self, t: float) -> None:
        """A move, jog, homing, velocity change or stop is about to be sent at host time ``t``."""
        if self._open:  # the rest the readings show after the last command closes its phase, before it is forgotten
            self._close()
        self.readings.note_command(t)
        with self._lock:
            self._stamp += 1
            self._phases.append([float(t), math.inf, float(self._stamp)])
            self._open = True

    def since(self, stamp: int) -> tuple[int, list[tuple[float, float]]]:
        """The phases opened or closed after ``stamp`` (0: every phase kept), and the stamp to ask with next."""
        if self._open:
            self._close()
        if stamp == self._stamp:
            return stamp, []
        with self._lock:
            return self._stamp, [(start, end) for start, end, changed in self._phases if changed > stamp]

    def phases(self) -> list[tuple[float, float]]:
        """Every phase kept, oldest first (``/api/status``, tests)."""
        return self.since(0)[1]

    def stated(self, start: float, end: float) -> list[list[float]]:
        """The phases overlapping ``start``–``end`` (s, host clock) as a recording states them
        (core/recording.py ``STAGE_PHASES``: [start, end, |a|]; one still open ends at ``end``): the calibration
        sweep's, from which the calibration learns what the stage does beyond its commands."""
        most = self.acceleration_mm_s2
        most = TUNABLES["stage_acceleration"].default if most is None else most
        return [[phase_start, min(phase_end, end), most] for phase_start, phase_end in self.phases()
                if phase_start <= end and phase_end >= start]

    def _close(self) -> None:
        rest = self.readings.rest_after_command()
        if rest is None:
            return
        with self._lock:
            if rest <= self._phases[-1][0]:  # a command came after the readings' rest: not this one's
                return
            self._stamp += 1
            for phase in self._phases:
                if phase[1] == math.inf:
                    phase[1], phase[2] = rest, float(self._stamp)
            self._open = False
