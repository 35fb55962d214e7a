"""OpenCV ``VideoCapture`` as a camera: a device index, a video file, or a stream URL.

Live sources buffer frames (V4L2 keeps several, network streams more), so reading them
naively hands out frames that are already old, and their age is unknown. For live sources a
grabber thread therefore pulls every frame as soon as the source offers it, stamps it, and keeps
it in a backlog bounded by the lag budget (``settings.max_lag_s``, see backlog.py); :meth:`read`
returns the oldest frame within that budget of the newest and counts the ones skipped as dropped. Files are read in
order, frame by frame, since a file has no "now"; a file
opened as live plays at full speed, or at its own frame rate with ``realtime=True`` (a camera
stand-in for tests).

Time: ``VideoCapture`` tells only when a frame was handed over (the moment ``grab`` returns),
not when it was exposed. The driver estimates mid-exposure as that grab time minus the sensor
readout (``readout_s``, 0 when unknown) minus half the exposure, and states its uncertainty as
one frame period: a frame may wait up to a period in the driver's queue before the grab sees it.
When the exposure is unknown (no ``exposure_us`` set and no ``exposure_s`` given) it is taken as
0 and half a period is added to the uncertainty.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from graytrack.drivers.camera.backlog import Backlog
from graytrack.drivers.camera.base import (
    Camera,
    CameraEndOfStream,
    CameraError,
    CameraNotFound,
    CameraSettingError,
    CameraSettings,
    CameraTimeout,
    Frame,
)
from graytrack.drivers.registry import cameras

if TYPE_CHECKING:
    from graytrack.drivers.config import CameraConfig

V4L2_EXPOSURE_UNIT_US = 100.0  # V4L2's exposure_time_absolute counts in units of 100 µs
BACKLOG_IMAGES = 32  # whole decoded images wait in the backlog: bounded in number, whatever the lag budget
UNKNOWN_PERIOD_S = 0.1  # the uncertainty when the source states no frame rate (10 Hz webcams exist)


@dataclass
class _Grabbed:
    seq: int
    image: np.ndarray
    t_grab: float
    t_device: float | None


def _is_live(source: int | str) -> bool:
    return isinstance(source, int) or "://" in source or source.startswith("/dev/")


@cameras.register("opencv")
class OpenCVCamera(Camera):
    @classmethod
    def from_config(cls, config: CameraConfig) -> OpenCVCamera:
        """The ``[camera]`` table's source (``device``: an index, a file or a URL) and timing."""
        assert config.device is not None  # CameraConfig requires it for this driver
        return cls(config.device, config.to_settings(), readout_s=config.readout_us * 1e-6)

    def __init__(
        self,
        source: int | str,
        settings: CameraSettings | None = None,
        live: bool | None = None,
        backend: int = cv2.CAP_ANY,
        readout_s: float = 0.0,
        exposure_s: float | None = None,
        realtime: bool = False,
    ) -> None:
        super().__init__(settings)
        if readout_s < 0 or (exposure_s is not None and exposure_s < 0):
            raise CameraSettingError("readout_s and exposure_s must not be negative")
        self.source = source
        self.live = _is_live(source) if live is None else live
        self.backend = backend
        self.readout_s = readout_s
        self.nominal_exposure_s = exposure_s
        self.realtime = realtime
        self._source_fps = 0.0
        self._cap: cv2.VideoCapture | None = None
        self._frame_dtype: np.dtype | None = None  # the last frame's, as decoded (bit_depth)
        self._cond = threading.Condition()
        self._backlog: Backlog[_Grabbed] = Backlog(BACKLOG_IMAGES)
        self._ended: str | None = None
        self._last_seq = -1
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _open_device(self) -> None:
        if isinstance(self.source, str) and not self.live and not Path(self.source).is_file():
            raise CameraNotFound(f"no video file at {self.source}")
        cap = cv2.VideoCapture(self.source, self.backend)
        if not cap.isOpened():
            raise CameraNotFound(f"OpenCV cannot open {self.source!r}")
        self._cap = cap
        self._source_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        try:
            if self.live:
                cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # a hint; the grabber thread is the guarantee
            self._apply_settings()
        except CameraError:
            cap.release()
            self._cap = None
            raise
        self._ended, self._last_seq = None, -1
        self._backlog.clear()
        if self.live:
            self._stop.clear()
            self._thread = threading.Thread(target=self._grab_loop, name="opencv-grabber", daemon=True)
            self._thread.start()

    def _close_device(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def _apply_settings(self) -> None:
        cap = self._cap
        assert cap is not None
        wanted = {
            cv2.CAP_PROP_EXPOSURE: None
            if self.settings.exposure_us is None
            else self.settings.exposure_us / V4L2_EXPOSURE_UNIT_US,
            cv2.CAP_PROP_GAIN: self.settings.gain_db,
            cv2.CAP_PROP_FPS: self.settings.frame_rate_hz,
        }
        for prop, value in wanted.items():
            if value is None:
                continue
            if not self.live:
                raise CameraSettingError(f"{self.source}: a video file has no exposure, gain or frame rate to set")
            if not cap.set(prop, float(value)):
                raise CameraSettingError(f"{self.source!r} refused property {prop} = {value}")
        width, height = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if width > 0 and height > 0:  # sources that state their size: refuse an ROI now, not at read
            self.settings.roi.crop(np.empty((height, width), dtype=np.uint8))

    # -- time ------------------------------------------------------------------------------
    @property
    def exposure_s(self) -> float:
        """The exposure set, else the nominal one given, else 0 (unknown)."""
        if self.settings.exposure_us is not None:
            return self.settings.exposure_us * 1e-6
        return self.nominal_exposure_s or 0.0

    @property
    def frame_period_s(self) -> float | None:
        rate = self.settings.frame_rate_hz or self._source_fps
        return 1.0 / rate if rate and rate > 0 else None

    @property
    def t_uncertainty_s(self) -> float:
        """Bound on |t_host - mid-exposure|: a frame period of queueing, half more if exposure is unknown."""
        period = self.frame_period_s or UNKNOWN_PERIOD_S
        known = self.settings.exposure_us is not None or self.nominal_exposure_s is not None
        return period if known else 1.5 * period

    @property
    def bit_depth(self) -> int | None:
        """8 once a frame decoded to 8 bits (OpenCV's default); before a frame, or for a 16-bit source handed out as
        it is, not known."""
        return 8 if self._frame_dtype == np.uint8 else None

    def mid_exposure(self, t_grab: float) -> float:
        """Mid-exposure estimated from the host time ``grab`` returned."""
        return t_grab - self.readout_s - 0.5 * self.exposure_s

    @property
    def source_ended(self) -> bool:
        """A live source's grabber has stopped (end of stream or error); frames may remain."""
        with self._cond:
            return self._ended is not None

    # -- frames ----------------------------------------------------------------------------
    def _read(self, timeout_s: float) -> Frame:
        return self._read_live(timeout_s) if self.live else self._read_file()

    def _read_file(self) -> Frame:
        cap = self._cap
        assert cap is not None
        ok = cap.grab()
        t_grab = time.monotonic()
        ok, image = cap.retrieve() if ok else (False, None)
        if not ok:
            raise CameraEndOfStream(f"{self.source}: end of video")
        frame_id = int(cap.get(cv2.CAP_PROP_POS_FRAMES)) - 1
        return self._frame(image, frame_id, t_grab, _device_time(cap, live=False))

    def _read_live(self, timeout_s: float) -> Frame:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while (grabbed := self._backlog.take(self.settings.max_lag_s, time.monotonic())) is None:
                if self._ended is not None:
                    raise CameraEndOfStream(f"{self.source}: {self._ended}")
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    self.stats.timeouts += 1
                    raise CameraTimeout(f"no frame from {self.source!r} within {timeout_s:g} s")
                self._cond.wait(remaining)
            self.stats.dropped += grabbed.seq - self._last_seq - 1
            self._last_seq = grabbed.seq
        return self._frame(grabbed.image, grabbed.seq, grabbed.t_grab, grabbed.t_device)

    def _grab_loop(self) -> None:
        cap = self._cap
        assert cap is not None
        seq = 0
        period = self.frame_period_s if self.realtime else None
        start = time.monotonic()
        while not self._stop.is_set():
            if period is not None and self._stop.wait(max(0.0, start + (seq + 1) * period - time.monotonic())):
                reason = "closed"
                break
            # A live camera's frames do not wait for a late host: those due a period ago or more are
            # lost (counted as dropped), not handed out in a burst stamped a few µs apart
            while period is not None and time.monotonic() - (start + (seq + 1) * period) > period and cap.grab():
                seq += 1
            if not cap.grab():
                reason = "end of stream"
                break
            t_grab = time.monotonic()
            ok, image = cap.retrieve()
            if not ok:
                reason = "frame could not be decoded"
                break
            with self._cond:
                self._backlog.push(t_grab, _Grabbed(seq, image, t_grab, _device_time(cap, live=True)),
                                   self.settings.max_lag_s)
                self._cond.notify_all()
            seq += 1
        else:
            reason = "closed"
        with self._cond:
            self._ended = reason
            self._cond.notify_all()

    def _frame(self, image: np.ndarray, frame_id: int, t_grab: float, t_device: float | None) -> Frame:
        mono = to_mono(image)
        self._frame_dtype = mono.dtype
        strip = self.settings.roi.crop(mono)
        return Frame(np.ascontiguousarray(strip), frame_id, self.mid_exposure(t_grab), t_device,
                     exposure_s=self.exposure_s, t_uncertainty_s=self.t_uncertainty_s)


def to_mono(image: np.ndarray) -> np.ndarray:
    """Gray levels from whatever OpenCV decoded: BGR, BGRA or already single-channel."""
    if image.ndim == 2:
        return image
    if image.shape[2] == 1:
        return image[:, :, 0]
    code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(image, code)


def _device_time(cap: cv2.VideoCapture, live: bool) -> float | None:
    """Media time of a file frame, or the driver's buffer timestamp of a live one.

    Backends without timestamps report 0 (or -1) for every live frame, which is no information.
    """
    msec = cap.get(cv2.CAP_PROP_POS_MSEC)
    if msec < 0 or (live and msec == 0):
        return None
    return msec / 1000.0
