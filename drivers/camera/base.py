"""The camera interface the service acquires through, whatever is behind it.

In the spirit of python-microscope's device classes: a small abstract class with an explicit
lifecycle (open/close, usable as a context manager), plain setters for the few settings this
sensor needs (exposure, gain, frame rate, the ROI strip), and frames that carry their own id and
timestamps. A frame is a strip of ``rows`` sensor rows by ``cols`` pixels, mono, in the camera's
native integer depth; the strip is what the tracker consumes, so nothing larger is handed out.

Time contract (the same for every driver): ``Frame.t_host`` is the *middle of the exposure* on
the host's ``time.monotonic`` clock, the clock the stage driver stamps position readings with
and the one every process on the machine shares, so a frame and a grating reading can be paired
and a client can compute a frame's age. ``Frame.exposure_s`` is the exposure's length on that
clock, so the exposure spans ``t_host ± exposure_s / 2``. ``Frame.t_uncertainty_s`` is the
driver's stated bound on how far ``t_host`` may be from the true mid-exposure: a camera that
only tells when a frame arrived gives a wider bound than one whose own clock is mapped to the
host's. ``t_device`` is the camera's own clock when it has one (seconds, arbitrary origin; the
simulated clock for the simulated camera), useful for exact frame spacing.
"""

from __future__ import annotations

import abc
import dataclasses
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from graytrack.drivers.camera.backlog import DEFAULT_MAX_LAG_S
from graytrack.drivers.device import Device


class CameraError(Exception):
    """Base of everything the camera drivers raise."""


class CameraTimeout(CameraError, TimeoutError):
    """No frame within the requested time."""


class CameraNotFound(CameraError):
    """The device, file or URL cannot be opened."""


class CameraUnavailable(CameraError):
    """The backend's libraries are not installed (for example Aravis/PyGObject)."""


class CameraSettingError(CameraError, ValueError):
    """A setting the camera refuses or the source cannot have (for example exposure of a file)."""


class CameraEndOfStream(CameraError):
    """A finite source (a video file) has no more frames."""


@dataclass(frozen=True)
class Roi:
    """A strip of the sensor: ``rows`` rows from ``row``, ``cols`` pixels from ``col``.

    ``cols=None`` means "to the right edge of the sensor". Increasing column is increasing target
    coordinate (docs/contracts.md's pixel index u).
    """

    row: int = 0
    rows: int = 1
    col: int = 0
    cols: int | None = None

    def __post_init__(self) -> None:
        if self.row < 0 or self.col < 0 or self.rows < 1 or (self.cols is not None and self.cols < 2):
            raise CameraSettingError(f"invalid ROI {self}: need row, col >= 0, rows >= 1, cols >= 2")

    def crop(self, image: np.ndarray) -> np.ndarray:
        """This strip of a full (height, width) image; refuses strips that do not fit."""
        height, width = image.shape[:2]
        cols = width - self.col if self.cols is None else self.cols
        if self.row + self.rows > height or self.col + cols > width or cols < 2:
            raise CameraSettingError(f"ROI {self} does not fit a {width}x{height} image")
        return image[self.row : self.row + self.rows, self.col : self.col + cols]


@dataclass(frozen=True)
class Frame:
    pixels: np.ndarray  # (rows, cols), mono
    frame_id: int
    t_host: float  # mid-exposure, time.monotonic seconds
    t_device: float | None = None  # the camera's own clock, seconds
    exposure_s: float = 0.0  # exposure length on the t_host clock
    t_uncertainty_s: float = 0.0  # stated bound on |t_host - true mid-exposure|

    @property
    def exposure_end(self) -> float:
        """When the exposure ended, host ``time.monotonic`` seconds."""
        return self.t_host + 0.5 * self.exposure_s


@dataclass
class CameraStats:
    """Counts since open: frames handed out, frames lost or skipped, incomplete buffers, timeouts."""

    delivered: int = 0
    dropped: int = 0
    incomplete: int = 0
    timeouts: int = 0


@dataclass
class CameraSettings:
    """What was asked for; ``None`` leaves the camera's own value alone."""

    exposure_us: float | None = None
    gain_db: float | None = None
    frame_rate_hz: float | None = None
    roi: Roi = field(default_factory=Roi)
    # The read policy, host side: how far behind the newest delivered frame a read still hands out
    # the older ones in order (see backlog.py). 0 = newest only.
    max_lag_s: float = DEFAULT_MAX_LAG_S
    # Reverse the pixel axis of every frame handed out: a camera mounted the other way round (its
    # column index running against the target coordinate, which docs/contracts.md's u must follow).
    flip: bool = False


class Camera(Device):
    """Open, optionally change settings, then ``read`` or iterate ``frames``; close."""

    def __init__(self, settings: CameraSettings | None = None) -> None:
        self.settings = settings if settings is not None else CameraSettings()
        self.stats = CameraStats()
        self._open = False

    # -- lifecycle -------------------------------------------------------------------------
    def open(self) -> None:
        if not self._open:
            self._open_device()
            self._open = True
            self.stats = CameraStats()

    def close(self) -> None:
        if self._open:
            self._open = False
            self._close_device()

    @property
    def is_open(self) -> bool:
        return self._open

    # -- time contract (drivers refine these) -----------------------------------------------
    @property
    def exposure_s(self) -> float:
        """The exposure frames are taken with, seconds on the camera's clock (0 when unknown)."""
        us = self.settings.exposure_us
        return 0.0 if us is None else us * 1e-6

    @property
    def t_uncertainty_s(self) -> float:
        """The bound this driver states on |Frame.t_host - true mid-exposure|."""
        return 0.0

    @property
    def bit_depth(self) -> int | None:
        """The bits of the readout, where the driver knows them (a sample at 2^bits − 1 sits clipped): recordings
        state it, and calibration and tracking set aside the samples at its limits. None: not known."""
        return None

    # -- settings --------------------------------------------------------------------------
    def set_exposure(self, exposure_us: float) -> None:
        _positive("exposure_us", exposure_us)
        self._apply("exposure_us", exposure_us)

    def set_gain(self, gain_db: float) -> None:
        self._apply("gain_db", gain_db)

    def set_frame_rate(self, frame_rate_hz: float) -> None:
        _positive("frame_rate_hz", frame_rate_hz)
        self._apply("frame_rate_hz", frame_rate_hz)

    def set_roi(self, roi: Roi) -> None:
        self._apply("roi", roi)

    def _apply(self, name: str, value: object) -> None:
        previous = getattr(self.settings, name)
        setattr(self.settings, name, value)
        if self._open:
            try:
                self._apply_settings()
            except CameraError:
                setattr(self.settings, name, previous)
                raise

    # -- frames ----------------------------------------------------------------------------
    def read(self, timeout_s: float = 1.0) -> Frame:
        """The next frame not handed out before, oldest first within ``settings.max_lag_s`` of the
        newest delivered (older ones are skipped and counted in ``stats.dropped``); never one older
        than the previous."""
        if not self._open:
            raise CameraError(f"{type(self).__name__} is not open")
        frame = self._read(timeout_s)
        if self.settings.flip:  # here, once for every driver: the strip's columns as the contract wants them
            frame = dataclasses.replace(frame, pixels=np.ascontiguousarray(frame.pixels[..., ::-1]))
        self.stats.delivered += 1
        return frame

    def frames(self, timeout_s: float = 1.0, count: int | None = None) -> Iterator[Frame]:
        """Iterate frames; ends after ``count`` frames or when a finite source runs out."""
        delivered = 0
        while count is None or delivered < count:
            try:
                yield self.read(timeout_s)
            except CameraEndOfStream:
                return
            delivered += 1

    def start_callback(
        self, callback: Callable[[Frame], None], timeout_s: float = 1.0
    ) -> "CallbackRunner":
        """Call ``callback`` from a thread for each frame until the returned runner is stopped."""
        runner = CallbackRunner(self, callback, timeout_s)
        runner.start()
        return runner

    # -- for implementations ---------------------------------------------------------------
    @abc.abstractmethod
    def _open_device(self) -> None:
        """Connect and apply ``self.settings``."""

    @abc.abstractmethod
    def _close_device(self) -> None: ...

    @abc.abstractmethod
    def _apply_settings(self) -> None:
        """Push ``self.settings`` to an open device; raise CameraSettingError if refused."""

    @abc.abstractmethod
    def _read(self, timeout_s: float) -> Frame: ...


class CallbackRunner:
    """Background delivery of frames to a callback; errors end the thread and are kept."""

    def __init__(self, camera: Camera, callback: Callable[[Frame], None], timeout_s: float) -> None:
        self.camera = camera
        self.callback = callback
        self.timeout_s = timeout_s
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="camera-callback", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, join_timeout_s: float = 2.0) -> None:
        self._stop.set()
        self._thread.join(join_timeout_s)

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self.camera.read(self.timeout_s)
            except CameraTimeout:
                continue
            except CameraEndOfStream:
                return
            except BaseException as exc:  # kept for the owner to inspect; the thread must not die silently
                self.error = exc
                return
            self.callback(frame)


def _positive(name: str, value: float) -> None:
    if not value > 0:
        raise CameraSettingError(f"{name} must be positive, got {value!r}")
