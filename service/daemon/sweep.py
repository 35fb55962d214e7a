"""The calibration sweep: step and settle over the stroke, then fit a model against the grating.

At each stop the stage is moved, the sweep waits until the controller reports on target, takes
the next frames whose exposure began *after* that moment (a frame straddling the settle would
blur the last of the motion into the calibration), and then reads the grating once more: the
axis is at rest, so that reading is the reference of every frame of the stop. Those frames form an ordinary :class:`Recording` which is calibrated with the
paper model (or the closed loop, ``model = "auto"``) and stored with the model and a report; the
recording is written first, so a failed fit still leaves the data behind for ``graytrack diagnose``.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import time
from typing import Any, Callable

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.errors import GraytrackError
from graytrack.core.models import save_model
from graytrack.core.models.fourier import FourierModel
from graytrack.core.recording import Recording, save
from graytrack.core.files import write_atomic
from graytrack.drivers.stage.base import Stage
from graytrack.service.daemon.acquisition import Acquisition, Sample
from graytrack.service.daemon.settings import SweepConfig
from graytrack.service.daemon import report_page
from graytrack.service.daemon.jobs import JobRunner
from graytrack.service.daemon.quality import held_out_quality
from graytrack.service.daemon.storage import Storage

log = logging.getLogger("graytrack.daemon")
SWEEP_SHARE = 0.8  # of the progress bar; the fit takes the rest


class SweepError(GraytrackError):
    """The sweep could not finish (stage, camera, limits); the message says which and why."""


def sweep_positions(limits: tuple[float, float], config: SweepConfig) -> np.ndarray:
    """Evenly spaced stops over the allowed range, ``margin_mm`` inside each limit."""
    low, high = limits[0] + config.margin_mm, limits[1] - config.margin_mm
    if not (math.isfinite(low) and math.isfinite(high) and high > low):
        raise SweepError(f"no room to sweep inside the limits [{limits[0]:g}, {limits[1]:g}] mm")
    return np.linspace(low, high, config.positions)


class Sweep:
    """The two steps of a calibration job (:class:`JobRunner` runs them and owns the states)."""

    def __init__(self, runner: JobRunner, stage: Stage, acquisition: Acquisition, storage: Storage,
                 config: SweepConfig, meta: dict[str, Any],
                 on_command: Callable[[float], None]) -> None:
        self.runner = runner
        self.job = runner.job
        self.stage = stage
        self.acquisition = acquisition
        self.storage = storage
        self.config = config
        self.meta = meta
        self.on_command = on_command  # the pairing must not assume rest across a commanded move

    def sweep(self) -> Recording:
        """Step, settle and record; the recording is saved before the fit (a failed fit keeps the data)."""
        recording = self._sweep()
        path = save(recording, self.storage.calibration_dir(self.job.id) / "recording.npz")
        self.job.files["recording"] = str(path)
        return recording

    def _sweep(self) -> Recording:
        positions = sweep_positions(self.stage.limits(), self.config)
        self.runner.enter("sweeping", 0.0, f"moving to the first of {len(positions)} stops")
        frames: list[np.ndarray] = []
        times: list[float] = []
        reference: list[float] = []
        feed = self.acquisition.subscribe()
        try:
            for i, target in enumerate(positions):
                self.job.check_abort()
                self.on_command(time.monotonic())
                self.stage.move_to(float(target))
                settled = self.stage.wait_on_target(self.config.settle_timeout_s).t  # host time, as frames
                self.job.check_abort()
                samples = self._settled_samples(feed, settled)
                # The axis is at rest inside its on-target window, so one POS? read after the frames
                # is the reference of all of them (pairing with the poller's readings could mix in
                # one taken before the move when polls are sparse).
                at_rest = self.stage.position().position_mm
                for sample in samples:
                    frames.append(np.asarray(sample.frame.pixels))
                    times.append(sample.t)
                    reference.append(at_rest)
                self.runner.update(SWEEP_SHARE * (i + 1) / len(positions),
                                   f"stop {i + 1}/{len(positions)} at {target:.3f} mm")
        finally:
            self.acquisition.unsubscribe(feed)
        strip = np.stack(frames)
        if strip.shape[1] == 1:
            strip = strip[:, 0, :]
        return Recording(strip, np.array(times), np.array(reference), dict(self.meta))

    def _settled_samples(self, feed: "queue.Queue[Sample]", settled_t: float) -> list[Sample]:
        """The next ``frames_per_position`` frames exposed entirely after ``settled_t``."""
        wanted, taken = self.config.frames_per_position, []
        deadline = time.monotonic() + self.config.frame_timeout_s
        while len(taken) < wanted:
            self.job.check_abort()
            try:
                sample = feed.get(timeout=max(0.0, min(0.25, deadline - time.monotonic())))
            except queue.Empty:
                if time.monotonic() >= deadline:
                    raise SweepError(f"the camera delivered {len(taken)} of {wanted} frames "
                                     f"within {self.config.frame_timeout_s:g} s") from None
                continue
            frame = sample.frame
            if frame.t_host - 0.5 * frame.exposure_s - frame.t_uncertainty_s > settled_t:  # began after the settle
                taken.append(sample)
        return taken

    def fit(self, recording: Recording) -> FourierModel:
        """The model of the job's kind, saved with its report in the calibration's folder."""
        self.runner.enter("fitting", SWEEP_SHARE, f"fitting the {self.job.model} model on {recording.n_frames} frames")
        folder = self.storage.calibration_dir(self.job.id)

        def progress(fraction: float, label: str) -> None:
            self.runner.update(SWEEP_SHARE + (1 - SWEEP_SHARE) * min(max(fraction, 0.0), 0.99), label)

        if self.job.model == "auto":
            from graytrack.core.diagnosis import diagnose
            from graytrack.service.report import write_report

            result = diagnose(recording, progress=progress)
            paths = write_report(result, folder)
            model, report = result.final_model, json.loads(paths["json"].read_text())
            after = report["after"]
            report["held_out"] = {"error_std_um": after["error_std_um"], "bound_um": report["noise"]["crlb_um"],
                                  "method": "closed loop (graytrack diagnose)"}
            report["summary"] = (f"closed loop: held-out error {after['error_std_um']:.2f} µm "
                                 f"(bound {report['noise']['crlb_um']:.2f} µm) after {len(report['steps'])} step(s)")
            self.job.files.update({name: str(p) for name, p in paths.items()})
        else:
            result = calibrate(recording, "paper", progress=progress)
            model = result.model
            self.runner.update(SWEEP_SHARE + 0.5 * (1 - SWEEP_SHARE), "held-out error: two-fold by stop")
            held_out = held_out_quality(recording, self.config.frames_per_position)
            quality = ("" if held_out is None else
                       f"held-out error {held_out['error_std_um']:.2f} µm (bound {held_out['bound_um']:.2f} µm), ")
            report = {
                "model": model.describe(),
                "rmse_gray": result.rmse_gray,
                "sigma_gray": result.sigma_gray,
                "iterations": result.iterations,
                "frames": recording.n_frames,
                "stroke_mm": float(np.ptp(recording.reference)),
                "period_mm": model.period_mm,
                "pixel_pitch_mm": model.pixel_pitch_mm,
                "held_out": held_out,
                "summary": f"paper model: {quality}rms {result.rmse_gray:.3f} gray (noise {result.sigma_gray:.3f} gray)",
            }
            self.job.files["model"] = str(save_model(model, folder / "model.json"))
            self.job.files["report"] = str(write_atomic(folder / "report.json", json.dumps(report, indent=1)))
            self.job.files["html"] = str(write_atomic(folder / "report.html", report_page.render(self.job.id, report)))
        self.job.report = report
        return model
