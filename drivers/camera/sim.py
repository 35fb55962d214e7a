"""The simulated camera: the virtual rig rendered at the stage's true position during exposure.

Frames come on a fixed frame clock like a free-running camera (slot k is exposed around
``t0 + k / frame_rate``); a frame exists once its exposure has ended, and :meth:`read` returns
the oldest such frame not handed out yet within the lag budget (``settings.max_lag_s``) of the
newest, waiting for the next one if none is ready: the buffer pool of a real camera, and the same
read policy as the other drivers. The stage's true positions at the start, middle
and end of the exposure go to the rig's renderer (:class:`FrameRenderer`, the same frames as
:meth:`VirtualRig.render` at a fraction of the cost per frame), so a moving stage blurs the strip as
it would on the bench, and the controller's ``POS?`` (the grating) stays a separate, imperfect
measurement of the same motion.

The rig may run in a process of its own (``source``, a :class:`RigProcess`: the stage's true motion,
its controller and the exposures out of the daemon's interpreter, drivers/sim/process.py): opening the
camera starts the child's frame clock, and a read takes the child's frames as the other drivers take a
camera's buffers (oldest first within the lag budget); the frames are the same. A rig process that
dies is a camera error naming its exit status, one that stops delivering a timeout; the camera cannot
be reopened while it is gone.

Time: the exposure slots and the stage's motion live on the simulated clock (which may run
faster than wall time); a frame's ``t_host`` is that slot's mid-exposure mapped to the host's
``time.monotonic`` and ``t_device`` is the simulated instant. The mapping is exact, so the
stated timing uncertainty is zero.
"""

from __future__ import annotations

import math
import time

import numpy as np

from graytrack.drivers.camera.backlog import first_slot
from graytrack.drivers.camera.base import Camera, CameraError, CameraSettingError, CameraSettings, CameraTimeout, Frame
from graytrack.drivers.clock import REAL_TIME, ScaledClock
from graytrack.drivers.registry import cameras
from graytrack.drivers.sim.frame_render import FrameRenderer
from graytrack.drivers.sim.process import RigProcess, RigProcessError, RigProcessTimeout
from graytrack.drivers.sim.rig import VirtualRig
from graytrack.drivers.sim.stage import Trajectory


@cameras.register("sim", simulated=True)  # it renders the virtual rig's stage: drivers/factory.py builds both
class SimCamera(Camera):
    def __init__(
        self,
        rig: VirtualRig,
        stage: Trajectory | None,
        settings: CameraSettings | None = None,
        clock: ScaledClock = REAL_TIME,
        source: RigProcess | None = None,
    ) -> None:
        super().__init__(settings)
        if (stage is None) == (source is None):
            raise ValueError("SimCamera renders either a stage's motion in process or a rig process's frames")
        self.rig = rig
        self.source = source  # the rig in its own process (drivers/sim/process.py), or None: rendered here
        # one frame at a time, the fixed part precomputed (frame_render.py)
        self.renderer = FrameRenderer(rig) if source is None else None
        self.stage = stage
        self.clock = clock
        self._t0 = 0.0
        self._last_slot = -1
        self.priority = 0  # SCHED_FIFO level of the rig process's exposures (raise_priority), 0 = normal

    @property
    def frame_rate_hz(self) -> float:
        return self.settings.frame_rate_hz or self.rig.frame_rate_hz

    @property
    def exposure_s(self) -> float:
        us = self.settings.exposure_us
        return self.rig.exposure_s if us is None else us * 1e-6

    def read(self, timeout_s: float = 1.0) -> Frame:
        if self.source is not None and not self.is_open and not self.source.alive:
            raise CameraError(self.source.describe())  # why it cannot be opened, not only that it is not
        return super().read(timeout_s)

    def raise_priority(self, level: int) -> None:
        """Expose at SCHED_FIFO ``level`` where the exposures run apart (the rig process): the frame loop's own."""
        self.priority = level
        if self.source is not None and self.is_open:
            self._configure()

    def _open_device(self) -> None:
        if self.source is not None and not self.source.alive:
            raise CameraError(self.source.describe() or "the virtual rig's process is not running")
        self._apply_settings()
        self._t0 = self.clock.now()
        self._last_slot = -1
        if self.source is not None:
            self._configure()

    def _configure(self) -> None:
        """The rig process's frame clock, from this camera's settings (on the rig's clock)."""
        assert self.source is not None
        try:
            self.source.configure(self._t0, self.frame_rate_hz, self.exposure_s,
                                  self.settings.max_lag_s * self.clock.scale, self.priority)
        except RigProcessError as exc:
            raise CameraError(str(exc)) from exc

    def _close_device(self) -> None:
        pass

    def _apply_settings(self) -> None:
        if self.settings.gain_db is not None:
            raise CameraSettingError("the simulated camera's gain is part of the rig scenario")
        if self.exposure_s * self.frame_rate_hz > 1.0:
            raise CameraSettingError(
                f"exposure {self.exposure_s * 1e6:g} us does not fit a frame period at {self.frame_rate_hz:g} Hz"
            )
        self.settings.roi.crop(np.empty((self.rig.n_rows, self.rig.n_pixels)))  # raises if it does not fit
        if self.source is not None and self.is_open:
            self._configure()  # a new rate or exposure while open: the child's clock follows

    def _slot_mid(self, slot: int) -> float:
        return self._t0 + 0.5 * self.exposure_s + slot / self.frame_rate_hz

    def _read(self, timeout_s: float) -> Frame:
        if self.source is not None:
            return self._take(timeout_s)
        now = self.clock.now()
        newest = math.floor((now - self._t0 - self.exposure_s) * self.frame_rate_hz)
        slot = first_slot(newest, self._last_slot + 1, self.settings.max_lag_s * self.clock.scale,
                          1.0 / self.frame_rate_hz)
        ready_at = self._slot_mid(slot) + 0.5 * self.exposure_s
        if self.clock.duration_to_host(ready_at - now) > timeout_s:
            self.stats.timeouts += 1
            raise CameraTimeout(f"no simulated frame within {timeout_s:g} s")
        self.clock.sleep(ready_at - now)
        self.stats.dropped += slot - self._last_slot - 1 if self._last_slot >= 0 else 0
        self._last_slot = slot
        t_mid = self._slot_mid(slot)
        half = 0.5 * self.exposure_s
        instants = np.array([t_mid - half, t_mid, t_mid + half]) if half > 0 else np.array([t_mid])
        assert self.renderer is not None and self.stage is not None
        strip = self.renderer.render(self.stage.position(instants), t_mid, self.exposure_s)
        pixels = np.ascontiguousarray(self.settings.roi.crop(strip))
        # Physics ran on the simulated clock; what leaves the camera is host time (the contract).
        return Frame(pixels, slot, self.clock.to_host(t_mid), t_device=t_mid,
                     exposure_s=self.clock.duration_to_host(self.exposure_s), t_uncertainty_s=0.0)

    def _take(self, timeout_s: float) -> Frame:
        """The rig process's next frame: the oldest waiting within the lag budget of now (else the newest
        waiting), as every driver takes a camera's buffers (backlog.py)."""
        assert self.source is not None
        try:
            slot, strip = self.source.next_frame(timeout_s)
            oldest_kept = time.monotonic() - self.settings.max_lag_s
            while self.clock.to_host(self._slot_mid(slot) + 0.5 * self.exposure_s) < oldest_kept:
                newer = self.source.next_frame(0.0, wait=False)
                if newer is None:
                    break
                slot, strip = newer
        except RigProcessTimeout as exc:
            self.stats.timeouts += 1
            raise CameraTimeout(str(exc)) from exc
        except RigProcessError as exc:
            raise CameraError(str(exc)) from exc
        self.stats.dropped += slot - self._last_slot - 1 if self._last_slot >= 0 else 0
        self._last_slot = slot
        t_mid = self._slot_mid(slot)
        pixels = np.ascontiguousarray(self.settings.roi.crop(strip))
        return Frame(pixels, slot, self.clock.to_host(t_mid), t_device=t_mid,
                     exposure_s=self.clock.duration_to_host(self.exposure_s), t_uncertainty_s=0.0)
