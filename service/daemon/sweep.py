"""The calibration sweep: record the stroke against the grating, then fit a model.

A **stop**: the stage is moved, the sweep waits until the controller reports on target, takes the
next frames whose exposure began *after* that moment (a frame straddling the settle would blur
the last of the motion into the calibration), and then reads the grating once more: the axis is
at rest, so that reading is the reference of every frame of the stop.

``kind = "stops"`` (the default): step and settle at ``positions`` stops.

``kind = "scan"``: a stop at each end of the stroke (frames at rest: the noise
estimate needs several at one place) and a pass at constant velocity up and one down (repeated,
up to ``MAX_ROUND_TRIPS``, while too few frames were paired), keeping
every frame whose grating reference is known (interpolated between the poller's bracketing
readings, :class:`Readings`; the acceleration at both ends gives none and those frames are left
out). A scan calibrates on frames in motion, as they are tracked during moves, and only motion
shows an error that follows velocity (the grating read off mid-exposure). Why both ways: every
position is seen at +v and at −v, so such an error cannot pass for one that follows position, and
the other way round (one pass and two stops at its ends confound them: on the `lab` rig the closed
loop read an offset of the stroke's ends as a 7 ms timing skew and tracked 4–15 µm off at rest).
What the print does along the stroke (dust, a smudge) the stops see as well: each frame sees
several millimetres of the target, at 41 shifts.

The frames form an ordinary :class:`Recording`, calibrated with the closed loop (``model =
"auto"``) or the paper model and stored with the model and a report; the recording is written
first, so a failed fit still leaves the data behind for ``graytrack diagnose``.
"""

from __future__ import annotations

import logging
import math
import queue
from collections import deque
from typing import Any, Callable

import numpy as np

from graytrack.core.errors import GraytrackError
from graytrack.core.models.fourier import FourierModel
from graytrack.core.recording import PIXEL_AXIS_REVERSED, STAGE_PHASES, Recording, save
from graytrack.drivers.stage.base import Stage
from graytrack.service.daemon.acquisition import Acquisition, Sample
from graytrack.service.daemon.clock import HOST_CLOCK, Clock
from graytrack.service.daemon.settings import SweepConfig
from graytrack.service.calibration_run import calibrate_recording, write_files
from graytrack.service.daemon.jobs import JobRunner
from graytrack.service.daemon.storage import Storage

log = logging.getLogger("graytrack.daemon")
SWEEP_SHARE = 0.8  # of the progress bar; the fit takes the rest
MIN_PASS_FRAMES = 50  # a pass that pairs fewer frames with the grating cannot calibrate anything
ON_TARGET_CHECK_S = 0.1  # how often the pass asks the controller whether it has arrived
PAIRING_MARGIN = 0.5  # the pass's velocity uses half the pairing tolerance for the readings' timing
MAX_ROUND_TRIPS = 3  # a scan goes up and down again while it has fewer than ENOUGH_SHARE of its frames
ENOUGH_SHARE = 0.8


class SweepError(GraytrackError):
    """The sweep could not finish (stage, camera, limits); the message says which and why."""


def sweep_range(limits: tuple[float, float], config: SweepConfig) -> tuple[float, float]:
    """The allowed range, ``margin_mm`` inside each limit."""
    low, high = limits[0] + config.margin_mm, limits[1] - config.margin_mm
    if not (math.isfinite(low) and math.isfinite(high) and high > low):
        raise SweepError(f"no room to sweep inside the limits [{limits[0]:g}, {limits[1]:g}] mm")
    return low, high


def sweep_positions(limits: tuple[float, float], config: SweepConfig) -> np.ndarray:
    """Evenly spaced stops over the allowed range, ``margin_mm`` inside each limit."""
    return np.linspace(*sweep_range(limits, config), config.positions)


class _Frames:
    """The recording being gathered: frames, their times and references, in order."""

    def __init__(self, meta: dict[str, Any]) -> None:
        self.meta = meta
        self.frames: list[np.ndarray] = []
        self.times: list[float] = []
        self.reference: list[float] = []

    def add(self, sample: Sample, reference_mm: float) -> None:
        self.frames.append(np.asarray(sample.frame.pixels))
        self.times.append(sample.t)
        self.reference.append(reference_mm)

    def recording(self) -> Recording:
        strip = np.stack(self.frames)
        if strip.shape[1] == 1:
            strip = strip[:, 0, :]
        return Recording(strip, np.array(self.times), np.array(self.reference), dict(self.meta))


class Sweep:
    """The two steps of a calibration job (:class:`JobRunner` runs them and owns the states)."""

    def __init__(self, runner: JobRunner, stage: Stage, acquisition: Acquisition, storage: Storage,
                 config: SweepConfig, meta: dict[str, Any],
                 on_command: Callable[[float], None], clock_scale: float = 1.0, clock: Clock = HOST_CLOCK,
                 stated: Callable[[float, float], list[list[float]]] | None = None) -> None:
        self.runner = runner
        self.job = runner.job
        self.stage = stage
        self.acquisition = acquisition
        self.storage = storage
        self.config = config
        self.meta = meta
        self.on_command = on_command  # the pairing must not assume rest across a commanded move
        # the phases of acceleration commanded between two instants (motion.py), stated in the recording
        # (core/recording.py STAGE_PHASES) when every motion of the stage is commanded through the daemon
        self.stated = stated
        self.clock_scale = clock_scale  # the stage's seconds per wall second (the virtual rig may run fast)
        self.clock = clock  # deadlines and waits for frames (host seconds, service/daemon/clock.py)

    def sweep(self) -> Recording:
        """Record the stroke; the recording is saved before the fit (a failed fit keeps the data)."""
        feed = self.acquisition.subscribe()
        try:
            recording = self._scan(feed) if self.config.kind == "scan" else self._stops(feed)
        finally:
            self.acquisition.unsubscribe(feed)
        if self.stated is not None and recording.n_frames:
            recording.meta[STAGE_PHASES] = self.stated(float(recording.t[0]), float(recording.t[-1]))
        path = save(recording, self.storage.calibration_dir(self.job.id) / "recording.npz")
        self.job.files["recording"] = str(path)
        return recording

    def _stops(self, feed: "queue.Queue[Sample]") -> Recording:
        positions = sweep_positions(self.stage.limits(), self.config)
        self.runner.enter("sweeping", 0.0, f"moving to the first of {len(positions)} stops")
        gathered = _Frames(self.meta)
        for i, target in enumerate(positions):
            self._stop_at(feed, float(target), gathered)
            self.runner.update(SWEEP_SHARE * (i + 1) / len(positions),
                               f"stop {i + 1}/{len(positions)} at {target:.3f} mm")
        return gathered.recording()

    def _stop_at(self, feed: "queue.Queue[Sample]", target: float, gathered: _Frames) -> None:
        self.job.check_abort()
        self.on_command(self.clock.now())
        self.stage.move_to(target)
        reading = self.stage.wait_on_target(self.config.settle_timeout_s)
        self.job.check_abort()  # a stop request halts the stage anywhere: that is an abort, not a displaced stop
        self._check_stop(target, reading.position_mm, "settled")
        samples = self._settled_samples(feed, reading.t)  # host time, as frames
        # The axis is at rest inside its on-target window, so one POS? read after the frames
        # is the reference of all of them (pairing with the poller's readings could mix in
        # one taken before the move when polls are sparse).
        at_rest = self.stage.position().position_mm
        self.job.check_abort()
        self._check_stop(target, at_rest, "after its frames")
        for sample in samples:
            gathered.add(sample, at_rest)

    def _check_stop(self, target: float, position_mm: float, when: str) -> None:
        """A stop is where it was planned (within ``stop_tolerance_um``), or the sweep fails saying where it was:
        frames recorded elsewhere would be fitted as if taken at the plan."""
        off_um = abs(position_mm - target) * 1e3
        if not off_um <= self.config.stop_tolerance_um:  # NaN too
            raise SweepError(f"the stop planned at {target:.4f} mm was at {position_mm:.4f} mm {when} "
                             f"({off_um:.1f} µm off, more than [sweep] stop_tolerance_um = "
                             f"{self.config.stop_tolerance_um:g}): something else moved the stage during the "
                             "calibration")

    def _scan(self, feed: "queue.Queue[Sample]") -> Recording:
        low, high = sweep_range(self.stage.limits(), self.config)
        self.runner.enter("sweeping", 0.0, f"moving to the start of the pass ({low:.3f} mm)")
        gathered = _Frames(self.meta)
        self._stop_at(feed, low, gathered)
        velocity, keep_every = self._scan_velocity(high - low)  # frames have flowed for a while: their rate is known
        paired = 0
        for round_trip in range(MAX_ROUND_TRIPS):
            # Readings answered late (a loaded host) pair no frame: go again, both ways, until the scan
            # has most of the frames it asked for.
            if round_trip and paired >= ENOUGH_SHARE * self.config.scan_frames:
                break
            share = (round_trip / MAX_ROUND_TRIPS, (round_trip + 1) / MAX_ROUND_TRIPS)
            middle = 0.5 * (share[0] + share[1])
            paired += self._pass(feed, low, high, velocity, keep_every, gathered, share=(share[0], middle))
            if round_trip == 0:
                self._stop_at(feed, high, gathered)
            paired += self._pass(feed, high, low, velocity, keep_every, gathered, share=(middle, share[1]))
        if paired < MIN_PASS_FRAMES:
            raise SweepError(f"the passes paired {paired} frames with the grating (fewer than {MIN_PASS_FRAMES}): "
                             f"poll the grating faster (grating_poll_s) or record more frames (scan_frames)")
        self.runner.update(SWEEP_SHARE, f"scan done: {paired} frames on the move, "
                                        f"{2 * self.config.frames_per_position} at rest")
        return gathered.recording()

    def _scan_velocity(self, stroke_mm: float) -> tuple[float, int]:
        """The velocity that gives ``scan_frames`` frames over the two passes, and one frame in how many
        to keep. At most the stage's own velocity, and slow enough that a reading's instant (known to
        half its round trip) stays within the pairing tolerance; a pass slowed for that keeps every
        k-th frame, so the fit gets about ``scan_frames`` still."""
        wall_rate = self.acquisition.frame_rate_hz(stale_after_s=2.0)
        if wall_rate <= 0:
            raise SweepError("the camera delivers no frames: nothing to scan with")
        frame_rate = wall_rate / self.clock_scale  # frames per second of the stage's clock
        velocity = min(2 * stroke_mm * frame_rate / self.config.scan_frames, self.stage.velocity())  # two passes
        readings = self.acquisition.readings
        half_round_trip = 0.5 * readings.typical_latency_s() * self.clock_scale
        if half_round_trip > 0:
            velocity = min(velocity, PAIRING_MARGIN * readings.tolerance_mm / half_round_trip)
        expected = 2 * stroke_mm * frame_rate / velocity
        return velocity, max(1, round(expected / self.config.scan_frames))

    def _pass(self, feed: "queue.Queue[Sample]", start: float, end: float, velocity: float, keep_every: int,
              gathered: _Frames, share: tuple[float, float]) -> int:
        """Move ``start`` → ``end`` at ``velocity`` keeping every ``keep_every``-th frame the grating pairs;
        returns their number. ``share`` is the part of the sweep's progress bar this pass fills."""
        readings = self.acquisition.readings
        previous = self.stage.velocity()
        waiting: deque[Sample] = deque()
        paired = seen = 0
        wall_s = abs(end - start) / velocity / self.clock_scale
        allowed_s = 2.0 * wall_s + self.config.settle_timeout_s
        deadline = self.clock.now() + allowed_s
        self.runner.update(SWEEP_SHARE * share[0], f"pass to {end:.3f} mm at {velocity:.3g} mm/s")
        self.stage.set_velocity(velocity)
        try:
            self.on_command(self.clock.now())
            self.stage.move_to(end)
            next_check = self.clock.now() + ON_TARGET_CHECK_S
            while True:
                self.job.check_abort()
                try:
                    waiting.append(self.clock.get(feed, 0.02))
                except queue.Empty:
                    pass
                latest = readings.latest()
                # A frame is paired once two readings after it exist (the bracketing one and the next): never
                # guessed ahead, and the motion is seen on both sides of its bracket (grating.py), so a busy
                # host's late reading costs no frame of the pass.
                while waiting and readings.newer(waiting[0].t) >= 2:
                    sample = waiting.popleft()
                    seen += 1
                    if seen % keep_every:
                        continue
                    reference = readings.at(sample.t)
                    if reference == reference:
                        gathered.add(sample, reference)
                        paired += 1
                if self.clock.now() < next_check:
                    continue
                next_check = self.clock.now() + ON_TARGET_CHECK_S
                if latest is not None:
                    done = min(max((latest[1] - start) / (end - start), 0.0), 1.0)
                    self.runner.update(SWEEP_SHARE * (share[0] + (share[1] - share[0]) * done),
                                       f"pass at {latest[1]:.3f} mm, {paired} frames")
                if self.stage.on_target() and abs(self.stage.position().position_mm - end) < 1e-3:
                    return paired
                if self.clock.now() > deadline:
                    raise SweepError(f"the pass did not reach {end:.3f} mm within {allowed_s:.0f} s")
        finally:
            self.stage.set_velocity(previous)

    def _settled_samples(self, feed: "queue.Queue[Sample]", settled_t: float) -> list[Sample]:
        """The next ``frames_per_position`` frames exposed entirely after ``settled_t``."""
        wanted, taken = self.config.frames_per_position, []
        deadline = self.clock.now() + self.config.frame_timeout_s
        while len(taken) < wanted:
            self.job.check_abort()
            try:
                sample = self.clock.get(feed, max(0.0, min(0.25, deadline - self.clock.now())))
            except queue.Empty:
                if self.clock.now() >= deadline:
                    raise SweepError(f"the camera delivered {len(taken)} of {wanted} frames "
                                     f"within {self.config.frame_timeout_s:g} s") from None
                continue
            frame = sample.frame
            if frame.t_host - 0.5 * frame.exposure_s - frame.t_uncertainty_s > settled_t:  # began after the settle
                taken.append(sample)
        return taken

    @staticmethod
    def _camera_flip(recording: Recording) -> bool:
        """Whether the frames were reversed at the camera ([camera] flip): the model holds for that
        orientation only, and the daemon refuses it under the other one."""
        return bool(recording.meta.get(PIXEL_AXIS_REVERSED, False))

    def fit(self, recording: Recording) -> FourierModel:
        """The model of the job's kind, written with its report in the calibration's folder."""
        self.runner.enter("fitting", SWEEP_SHARE, f"fitting the {self.job.model} model on {recording.n_frames} frames")

        def progress(fraction: float, label: str) -> None:
            self.runner.update(SWEEP_SHARE + (1 - SWEEP_SHARE) * min(max(fraction, 0.0), 0.99), label)

        # held out as `graytrack calibrate` holds out the same recording (its stops, read off it)
        run = calibrate_recording(recording, self.job.model, progress=progress,
                                  info={"camera_flip": self._camera_flip(recording)})
        # the job keeps what was written
        paths = write_files(run, self.storage.calibration_dir(self.job.id), self.job.id)
        self.job.files.update({name: str(path) for name, path in paths.items()})
        self.job.report = run.report
        run.raise_if_refused()  # the report says why; the job fails with the cause and its fix
        return run.model
