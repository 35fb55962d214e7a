"""GigE Vision and USB3 Vision cameras through Aravis 0.8 (GObject introspection).

Aravis and PyGObject are optional system-level dependencies, so nothing here imports ``gi``
until a camera is opened; :func:`load_aravis` raises :class:`CameraUnavailable` with the
install hint when they are missing.

Acquisition: a stream with a pool of pre-allocated buffers, filled by Aravis's own thread.
:meth:`AravisCamera.read` takes every filled buffer waiting, checks its status (incomplete
buffers are counted and recycled, never handed out), copies the ROI strip out and gives the
buffer straight back to the pool, so the pool stays free for the camera however late the reader
is. The strips wait in a host-side backlog and are handed out oldest first within the lag budget
(``settings.max_lag_s``, see backlog.py): a late reader loses no frame, a slow one gets current
frames rather than an ever older backlog. Gaps in the camera's frame ids between frames handed
out (lost in transit, or skipped for the budget) are counted as dropped.

Time: a buffer carries the camera's own timestamp (exact spacing, unknown origin, a few ppm of
drift) and the host's receive time (exact clock, but late by scheduling jitter and now and then
by milliseconds). :class:`~graytrack.drivers.camera.clock_fit.DeviceClockFit` maps the first
onto the second by an online offset-and-drift fit on the lower envelope, and the frame's
``t_host`` is that mapped arrival minus the readout (``readout_s``) minus half the exposure the
camera reports: mid-exposure on ``time.monotonic``. Until the fit has 1.6 s of frames the
stated uncertainty is a frame period (as for a receive-time stamp); then it is three times the
envelope's scatter plus ``TIMING_FLOOR_S``.

Triggering: ``free-run`` (continuous at the frame rate), ``software`` (each read fires the
trigger and waits for that frame), ``hardware`` (frames start on ``trigger_source``).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from graytrack.drivers.camera.backlog import Backlog
from graytrack.drivers.camera.base import (
    Camera,
    CameraError,
    CameraNotFound,
    CameraSettingError,
    CameraSettings,
    CameraTimeout,
    CameraUnavailable,
    Frame,
)
from graytrack.drivers.camera.clock_fit import DeviceClockFit
from graytrack.drivers.registry import cameras

if TYPE_CHECKING:
    from graytrack.drivers.config import CameraConfig

TriggerMode = Literal["free-run", "software", "hardware"]
PIXEL_DTYPES = {"Mono8": np.uint8, "Mono10": np.uint16, "Mono12": np.uint16, "Mono16": np.uint16}
PIXEL_BITS = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono16": 16}  # what each format reads out, unpacked
GVSP_FRAME_ID_MODULUS = 1 << 16  # GigE Vision 1.x block ids are 16 bits and skip 0 on wrap
TIMING_FLOOR_S = 100e-6  # host wake-up and clock-conversion jitter left after the envelope fit

_aravis_module: Any = None


def load_aravis() -> Any:
    """Import ``gi.repository.Aravis`` 0.8 on first use."""
    global _aravis_module
    if _aravis_module is None:
        try:
            import gi

            gi.require_version("Aravis", "0.8")
            from gi.repository import Aravis
        except (ImportError, ValueError) as exc:
            raise CameraUnavailable(
                "Aravis 0.8 via PyGObject is not available: install gir1.2-aravis-0.8 (apt) and "
                f"the 'aravis' extra (PyGObject<3.51); {exc}"
            ) from None
        _aravis_module = Aravis
    return _aravis_module


@cameras.register("aravis")
class AravisCamera(Camera):
    @classmethod
    def from_config(cls, config: CameraConfig) -> AravisCamera:
        """The ``[camera]`` table's device (None: the first Aravis finds), trigger, pixel format and timing."""
        return cls(
            None if config.device is None else str(config.device),
            config.to_settings(),
            trigger=config.trigger,
            trigger_source=config.trigger_source,
            pixel_format=config.pixel_format,
            n_buffers=config.n_buffers,
            readout_s=config.readout_us * 1e-6,
        )

    def __init__(
        self,
        device_id: str | None = None,
        settings: CameraSettings | None = None,
        trigger: TriggerMode = "free-run",
        trigger_source: str = "Line0",
        pixel_format: str = "Mono8",
        n_buffers: int = 8,
        readout_s: float = 0.0,
    ) -> None:
        super().__init__(settings)
        if pixel_format not in PIXEL_DTYPES:
            raise CameraSettingError(f"pixel format {pixel_format!r} is not one of {sorted(PIXEL_DTYPES)}")
        if trigger not in ("free-run", "software", "hardware"):
            raise CameraSettingError(f"trigger must be free-run, software or hardware, got {trigger!r}")
        self.device_id = device_id
        self.trigger = trigger
        self.trigger_source = trigger_source
        self.pixel_format = pixel_format
        self.n_buffers = max(2, n_buffers)
        if readout_s < 0:
            raise CameraSettingError(f"readout_s must not be negative, got {readout_s}")
        self.readout_s = readout_s
        self.clock_fit = DeviceClockFit()
        self._exposure_s = 0.0
        self._period_s = 0.1
        self._aravis: Any = None
        self._camera: Any = None
        self._stream: Any = None
        self._region: tuple[int, int, int, int] = (0, 0, 0, 0)
        self._last_frame_id: int | None = None
        self._backlog: Backlog[Frame] = Backlog()

    @property
    def exposure_s(self) -> float:
        """The exposure the camera reports using, seconds."""
        return self._exposure_s

    @property
    def t_uncertainty_s(self) -> float:
        fit = self.clock_fit
        if not fit.established:
            return self._period_s + fit.spread_s
        return 3.0 * fit.spread_s + TIMING_FLOOR_S

    @property
    def bit_depth(self) -> int:
        return PIXEL_BITS[self.pixel_format]

    @property
    def model(self) -> str:
        return "" if self._camera is None else f"{self._camera.get_vendor_name()} {self._camera.get_model_name()}"

    # -- lifecycle -------------------------------------------------------------------------
    def _open_device(self) -> None:
        aravis = self._aravis = load_aravis()
        if self.device_id is not None and self.device_id.startswith("Fake"):
            aravis.enable_interface("Fake")
        try:
            self._camera = aravis.Camera.new(self.device_id)
        except Exception as exc:  # GLib.Error; its class lives in gi, which is optional
            raise CameraNotFound(f"Aravis cannot open camera {self.device_id or '(first found)'}: {exc}") from None
        self.clock_fit = DeviceClockFit()
        try:
            self._configure()
        except Exception:
            self._camera = None
            raise

    def _close_device(self) -> None:
        self._stop_stream()
        self._camera = None

    def _configure(self) -> None:
        """Pixel format, trigger and settings; the stream is (re)built for the new payload."""
        self._stop_stream()
        camera = self._camera
        _call("pixel format", camera.set_pixel_format_from_string, self.pixel_format)
        _call("acquisition mode", camera.set_acquisition_mode, self._aravis.AcquisitionMode.CONTINUOUS)
        if self.trigger == "free-run":
            _call("trigger", camera.clear_triggers)
        elif self.trigger == "software":
            if not camera.is_software_trigger_supported():
                raise CameraSettingError(f"{self.model} has no software trigger")
            _call("trigger", camera.set_trigger, "Software")
        else:
            _call("trigger", camera.set_trigger, self.trigger_source)
        self._apply_settings()

    def _apply_settings(self) -> None:
        camera = self._camera
        restart = self._stream is not None
        self._stop_stream()
        s = self.settings
        self._region = self._fit_region()
        _call("region", camera.set_region, *self._region)
        if s.exposure_us is not None:
            _call("exposure", camera.set_exposure_time, float(s.exposure_us))
        if s.gain_db is not None:
            _call("gain", camera.set_gain, float(s.gain_db))
        if s.frame_rate_hz is not None and self.trigger == "free-run":
            _call("frame rate", camera.set_frame_rate, float(s.frame_rate_hz))
        # What the camera really uses (it rounds): read once here, not per frame over the wire.
        self._exposure_s = max(0.0, float(_call("exposure", camera.get_exposure_time))) * 1e-6
        rate = float(_call("frame rate", camera.get_frame_rate))
        self._period_s = 1.0 / rate if rate > 0 else 0.1
        if restart:
            self._start_stream()

    def _fit_region(self) -> tuple[int, int, int, int]:
        """The sensor region to read: the ROI strip, widened to the camera's size increments."""
        camera, roi = self._camera, self.settings.roi
        width, height = camera.get_sensor_size()
        cols = width - roi.col if roi.cols is None else roi.cols
        if roi.col + cols > width or roi.row + roi.rows > height:
            raise CameraSettingError(f"ROI {roi} does not fit the {width}x{height} sensor")
        x_inc = max(1, camera.get_x_offset_increment())
        y_inc = max(1, camera.get_y_offset_increment())
        x, y = roi.col - roi.col % x_inc, roi.row - roi.row % y_inc
        w = _round_up(roi.col + cols - x, max(1, camera.get_width_increment()))
        h = _round_up(roi.row + roi.rows - y, max(1, camera.get_height_increment()))
        return x, y, min(w, width - x), min(h, height - y)

    def _start_stream(self) -> None:
        try:
            stream = self._camera.create_stream(None, None)
        except Exception as exc:
            raise CameraError(f"cannot create a stream for {self.model}: {exc}") from None
        payload = self._camera.get_payload()
        for _ in range(self.n_buffers):
            stream.push_buffer(self._aravis.Buffer.new_allocate(payload))
        self._stream = stream
        self._last_frame_id = None
        self._backlog.clear()
        _call("start acquisition", self._camera.start_acquisition)

    def _stop_stream(self) -> None:
        if self._stream is None:
            return
        try:
            self._camera.stop_acquisition()
        except Exception:
            pass  # the device may already be gone; dropping the stream is what matters
        self._stream = None

    # -- frames ----------------------------------------------------------------------------
    def _read(self, timeout_s: float) -> Frame:
        if self._stream is None:
            self._start_stream()
        stream = self._stream
        deadline = time.monotonic() + timeout_s
        if self.trigger == "software":
            self._camera.software_trigger()
        while True:
            while (buffer := stream.try_pop_buffer()) is not None:
                self._keep(stream, buffer)
            frame = self._backlog.take(self.settings.max_lag_s, time.monotonic())
            if frame is not None:
                break
            remaining_us = int((deadline - time.monotonic()) * 1e6)
            buffer = stream.timeout_pop_buffer(remaining_us) if remaining_us > 0 else None
            if buffer is None:
                self.stats.timeouts += 1
                raise CameraTimeout(f"no frame from {self.model} within {timeout_s:g} s")
            self._keep(stream, buffer)
        self.stats.dropped += frames_between(self._last_frame_id, frame.frame_id)
        self._last_frame_id = frame.frame_id
        return frame

    def _keep(self, stream: Any, buffer: Any) -> None:
        """A filled buffer's strip into the backlog (incomplete ones are counted); the buffer back to the pool."""
        try:
            if buffer.get_status() == self._aravis.BufferStatus.SUCCESS:
                frame = self._frame(buffer)
                self._backlog.push(frame.exposure_end + self.readout_s, frame, self.settings.max_lag_s)
            else:
                self.stats.incomplete += 1
        finally:
            stream.push_buffer(buffer)

    def _frame(self, buffer: Any) -> Frame:
        width, height = buffer.get_image_width(), buffer.get_image_height()
        dtype = PIXEL_DTYPES[self.pixel_format]
        image = np.frombuffer(buffer.get_data(), dtype=dtype, count=width * height).reshape(height, width)
        x, y = self._region[:2]
        roi = self.settings.roi
        cols = self._region[2] - (roi.col - x) if roi.cols is None else roi.cols
        strip = image[roi.row - y : roi.row - y + roi.rows, roi.col - x : roi.col - x + cols].copy()
        return Frame(strip, int(buffer.get_frame_id()), self._mid_exposure(buffer), buffer.get_timestamp() * 1e-9,
                     exposure_s=self._exposure_s, t_uncertainty_s=self.t_uncertainty_s)

    def _mid_exposure(self, buffer: Any) -> float:
        arrival = _host_time(buffer.get_system_timestamp())
        device_ns = int(buffer.get_timestamp())
        if device_ns > 0:  # 0: the transport layer gave no device timestamp
            self.clock_fit.add(device_ns, arrival)
            arrival = self.clock_fit.host_time(device_ns)
        return arrival - self.readout_s - 0.5 * self._exposure_s


def frames_between(last: int | None, current: int) -> int:
    """Frames the camera produced between two delivered ones (lost in transit or skipped).

    GigE Vision 1.x block ids are 16 bits and skip 0 when they wrap.
    """
    if last is None:
        return 0
    gap = current - last - 1
    if gap < 0 and last < GVSP_FRAME_ID_MODULUS:
        gap = (current - 1) + (GVSP_FRAME_ID_MODULUS - 1 - last)
    return max(0, gap)


def _host_time(system_timestamp_ns: int) -> float:
    """Aravis's host timestamp (wall clock, ns) on the monotonic clock the stage also uses."""
    age_s = (time.time_ns() - system_timestamp_ns) * 1e-9
    return time.monotonic() - age_s


def _round_up(value: int, step: int) -> int:
    return -(-value // step) * step


CONTROL_ATTEMPTS = 3  # a GigE Vision control packet lost on a busy link or host times out; the next usually passes


def _call(what: str, method: Any, *args: Any) -> Any:
    """A control call to the device; retried when it timed out (GVCP runs over UDP: a lost
    packet is a timeout, not a refusal), refused with the device's reason otherwise."""
    for attempt in range(CONTROL_ATTEMPTS):
        try:
            return method(*args)
        except Exception as exc:  # GLib.Error from the device
            if "timeout" not in str(exc).lower() or attempt == CONTROL_ATTEMPTS - 1:
                raise CameraSettingError(f"camera refused {what} {args if args else ''}: {exc}") from None
    raise AssertionError("unreachable")
