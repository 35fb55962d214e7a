"""The stage as the API drives it: moves within the soft limits, jogs from the grating's position,
the reference move, the velocity, and stop.

Apart from the rig so that what a move may do is in one place: it refuses while a calibration
moves the stage (a stop aborts that calibration first, then stops), marks the command for the
grating's pairing (a frame is not paired across a commanded move) and the estimator's commanded motion
(motion.py), and logs one event per action.
Answers are the API's response models.

"Is a calibration running?" and the command that follows are one step under :attr:`StageControl.motion`,
the lock the rig also holds while it starts a calibration: without it a move checked before the job
existed reached the controller after the sweep's first move, and the sweep recorded its first stop at
the move's target (2.0 mm for a planned 0.1 mm). A stop takes no lock: it must never wait.
"""

from __future__ import annotations

import math
import threading
import time
from contextlib import contextmanager
from typing import Any, Callable, Iterator

from graytrack.drivers.factory import Hardware
from graytrack.drivers.stage.errors import StageError, StageLimitError
from graytrack.service.daemon.errors import Busy, NotReady, OutOfLimits
from graytrack.service.daemon.motion import CommandedMotion
from graytrack.wire import Homed, Moved, Stopped, Velocity

MAX_VELOCITY_MM_S = 100.0
SHOWN_DIGITS = 6  # significant digits of a refused value and its limits, more only where they would read equal
MAX_DIGITS = 17  # enough for any float64 to read back as itself


def shown(value: float, *limits: float) -> list[str]:
    """``value`` and ``limits`` as text with the fewest significant digits (at least :data:`SHOWN_DIGITS`)
    that keep ``value`` apart from every limit it differs from: 10.4600000001 against 10.46 reads
    "10.4600000001", not "10.46 is outside [0, 10.46]"."""
    numbers = (value, *limits)
    for digits in range(SHOWN_DIGITS, MAX_DIGITS + 1):
        texts = [f"{number:.{digits}g}" for number in numbers]
        if all(texts[0] != text for limit, text in zip(limits, texts[1:]) if limit != value):
            return texts
    return [repr(number) for number in numbers]


class StageControl:
    """``ready()`` gives the open hardware (or raises NotReady); ``active_job()`` the id of a
    calibration moving the stage, if any; ``abort_job(reason)`` aborts it and gives its id;
    ``grating_mm()`` the latest grating position; ``event(kind, message, **details)`` logs."""

    def __init__(self, ready: Callable[[], Hardware], active_job: Callable[[], str | None],
                 abort_job: Callable[[str], str | None], commands: CommandedMotion,
                 grating_mm: Callable[[], float | None], event: Callable[..., None]) -> None:
        self._ready, self._active_job, self._abort_job = ready, active_job, abort_job
        # every command is noted before it is sent: the grating's pairing assumes no rest across it, the estimator
        # allows the stage's acceleration from it until the readings show the stage at rest again (motion.py)
        self._commands, self._grating_mm, self._event = commands, grating_mm, event
        # held from the check for a calibration to the end of the command; the rig holds it to start one
        self.motion = threading.RLock()
        self.target_mm: float | None = None  # the last commanded target (the page's moving indicator)
        self.velocity_mm_s: float | None = None
        self.velocity_limit_mm_s: float | None = None

    def attached(self, hardware: Hardware) -> None:
        """The velocity in force and the controller's limit (asked once: it is the controller's)."""
        self.velocity_mm_s = hardware.stage.velocity()
        self.velocity_limit_mm_s = hardware.stage.velocity_limit()

    @contextmanager
    def _idle(self) -> Iterator[Hardware]:
        """The hardware, while no calibration can start (the command runs inside)."""
        with self.motion:
            hardware = self._ready()
            job = self._active_job()
            if job is not None:
                raise Busy(f"calibration {job} is moving the stage; POST /api/stage/stop aborts it")
            yield hardware

    def _command(self, action: Callable[[], Any]) -> Any:
        """Run a stage command: a value it refuses is 422, a stage that fails is 503."""
        self._commands.note_command(time.monotonic())
        try:
            return action()
        except StageLimitError as exc:
            raise OutOfLimits(str(exc)) from None
        except StageError as exc:
            raise NotReady(f"stage: {exc}") from None

    def move(self, target_mm: float) -> Moved:
        with self._idle() as hardware:
            low, high = hardware.stage.limits()
            if not (math.isfinite(target_mm) and low <= target_mm <= high):
                target, low_text, high_text = shown(target_mm, low, high)
                raise OutOfLimits(f"target_mm {target} is outside the soft limits [{low_text}, {high_text}] mm")
            self._command(lambda: hardware.stage.move_to(target_mm))
            self.target_mm = target_mm
        self._event("move", f"move to {target_mm:g} mm", target_mm=target_mm)
        return Moved(target_mm=target_mm, limits_mm=[low, high])

    def jog(self, step_mm: float) -> Moved:
        """A relative move by ``step_mm`` from where the grating says the stage is."""
        position = self._grating_mm()
        if position is None:
            raise NotReady("no grating reading yet: the stage position is unknown")
        if not math.isfinite(step_mm) or step_mm == 0:
            raise OutOfLimits("step_mm must be a non-zero finite number")
        return self.move(round(position + step_mm, 6))

    def home(self) -> Homed:
        """The reference move: the controller finds its reference mark again (the stage moves)."""
        with self._idle() as hardware:
            self.target_mm = None
            self._command(hardware.stage.reference)
        self._event("home", "reference move done")
        return Homed(referenced=True)

    def set_velocity(self, velocity_mm_s: float) -> Velocity:
        with self._idle() as hardware:
            self.velocity_mm_s = self._velocity(hardware, velocity_mm_s)
        self._event("velocity", f"velocity set to {self.velocity_mm_s:g} mm/s")
        return Velocity(velocity_mm_s=self.velocity_mm_s)

    def _velocity(self, hardware: Hardware, velocity_mm_s: float) -> float:
        controller = self.velocity_limit_mm_s
        highest = MAX_VELOCITY_MM_S if controller is None else min(MAX_VELOCITY_MM_S, controller)
        if not (math.isfinite(velocity_mm_s) and 0 < velocity_mm_s <= highest):
            lower = controller is not None and controller < MAX_VELOCITY_MM_S
            whose = "the controller's limit" if lower else "the limit"
            velocity, highest_text = shown(velocity_mm_s, highest)
            raise OutOfLimits(f"velocity_mm_s {velocity} is outside (0, {highest_text}] mm/s ({whose})")

        def apply() -> float:
            hardware.stage.set_velocity(velocity_mm_s)
            return hardware.stage.velocity()

        return float(self._command(apply))

    def stop(self) -> Stopped:
        """Stop the stage now; an active calibration is aborted first (it would move it again).
        The abort is requested before anything can fail, so a stop always ends a job."""
        aborted = self._abort_job("calibration aborted by a stop request")
        hardware = self._ready()
        self._command(hardware.stage.stop)
        self._event("stop", "stage stopped" + (f", calibration {aborted} aborted" if aborted else ""))
        return Stopped(stopped=True, aborted_calibration=aborted)
