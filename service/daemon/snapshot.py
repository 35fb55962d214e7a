"""What the rig is doing at one instant, read once from its parts: what ``/api/status``,
``/healthz`` and ``/metrics`` are made from.

Why a snapshot and not the :class:`Rig` itself: the status document, the health answer and the
Prometheus text each derive several figures from the same parts (is the newest frame fresh? is a
model installed?). Read from the live parts one by one, two figures of one answer could come from
two different frames; read into a frozen record first, they all describe one instant, and the
modules that turn it into JSON or text depend on this record only, not on the rig's attributes,
its locks or its threads. Each part is read through a small protocol (what the snapshot needs of
it, nothing more), so a new figure is a field here and a line in the part's ``read`` function.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, Mapping, Protocol

from graytrack.service.daemon.supervision import sentence

if TYPE_CHECKING:
    from graytrack.service.daemon.acquisition import AcquisitionStats

JOB_FIELDS = ("id", "state", "progress", "message", "error")


class TrimPart(Protocol):
    def status(self) -> dict[str, Any]: ...


class AcquisitionPart(Protocol):
    """What the snapshot reads of the frame loop (:class:`~graytrack.service.daemon.acquisition.Acquisition`)."""

    stats: "AcquisitionStats"
    crashes: int
    trim: TrimPart
    slide: TrimPart | None  # without a grating: the slide each bound carries (service/daemon/slide.py)

    @property
    def tracker(self) -> object | None: ...

    @property
    def model_stale(self) -> str | None: ...

    def frame_rate_hz(self, stale_after_s: float) -> float: ...

    def seconds_since_tracked(self) -> float: ...


class GratingPart(Protocol):
    """What the snapshot reads of the grating poller (:class:`~graytrack.service.daemon.grating.GratingPoller`)."""

    reads: int
    errors: int
    crashes: int

    def fresh_mm(self, max_age_s: float) -> float | None: ...

    def silent_s(self) -> float | None: ...


@dataclass(frozen=True)
class Counters:
    """The frame loop's counters since start (``/metrics`` families, ``frames`` and ``dropped`` in the status)."""

    frames: int
    tracked: int
    unplaced: int  # tracked frames the solver could not place
    lock_events: int
    camera_errors: int
    tracking_errors: int
    dropped: int  # gaps in the camera's frame_id sequence

    @classmethod
    def of(cls, stats: "AcquisitionStats") -> "Counters":
        return cls(**{counter.name: getattr(stats, counter.name) for counter in fields(cls)})


@dataclass(frozen=True)
class FrameLoop:
    """The frame loop's figures: the newest tracked frame's record and its age, the counters."""

    last_message: Mapping[str, Any] | None
    seconds_since_tracked: float
    frame_rate_hz: float
    tracker_ready: bool
    model_stale: str | None  # the family of causes the tracker's model is stale for (None: it holds)
    counters: Counters
    crashes: int
    trim: Mapping[str, Any]
    slide: Mapping[str, Any] | None = None  # None: a grating is read (nothing carried)


@dataclass(frozen=True)
class Grating:
    """The grating poller's figures: the newest reading while fresh, its age, the counters."""

    fresh_mm: float | None
    silent_s: float | None
    moving: bool | None
    reads: int
    errors: int
    crashes: int


@dataclass(frozen=True)
class Devices:
    """What the open hardware says of itself."""

    limits_mm: tuple[float, float]
    camera_dropped: int  # frames the camera lost or skipped
    stage_reconnects: int  # serial port reopened (0 for a stage without a serial link)


@dataclass(frozen=True)
class RigSnapshot:
    """The rig at one instant. ``None`` for a part means it is not there (yet): no hardware open,
    no frame loop, no model, no job."""

    closing: bool
    faults: Mapping[str, str]
    faults_raised: int
    devices: Devices | None
    frame_loop: FrameLoop | None
    grating: Grating | None
    model: str | None  # the installed model, described
    job: Mapping[str, Any] | None  # the newest job's id, state, progress, message, error
    job_active: bool
    active_calibration: Mapping[str, Any] | None
    target_mm: float | None
    velocity_mm_s: float | None
    calibrations_finished: Mapping[str, int]
    simulated: bool
    stale_after_s: float
    uptime_s: float
    texture: Mapping[str, Any] | None = None  # the marks learned on the print (texture_store.py; None: no frame loop)
    sensor_map: Mapping[str, Any] | None = None  # the sensor's side learned (sensor_map_store.py; None: none kept)
    print_map: Mapping[str, Any] | None = None  # the print the estimator learned (print_map_store.py; None: none kept)
    reason: str | None = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "reason", sentence(dict(self.faults)))

    @property
    def calibrated(self) -> bool:
        return self.model is not None

    @property
    def state(self) -> str:
        """stopping > fault > starting > calibrating > tracking > idle (the module doc of ``rig``)."""
        if self.closing:
            return "stopping"
        if self.faults:
            return "fault"
        if self.frame_loop is None:
            return "starting"
        if self.job_active:
            return "calibrating"
        return "tracking" if self.model is not None else "idle"

    @property
    def newest_fresh(self) -> bool:
        """A tracked frame exists and is younger than ``stale_after_s`` (its figures may be shown)."""
        loop = self.frame_loop
        return (loop is not None and loop.last_message is not None
                and loop.seconds_since_tracked <= self.stale_after_s)

    @property
    def tracking_fresh(self) -> bool:
        """Frames are being tracked now with an installed model and no fault (``/healthz`` 200 unless stale)."""
        loop = self.frame_loop
        return (loop is not None and self.model is not None and loop.tracker_ready
                and loop.seconds_since_tracked <= self.stale_after_s and not self.faults)

    @property
    def model_stale(self) -> str | None:
        """The family the installed model is stale for (None: it holds, or no model)."""
        return self.frame_loop.model_stale if self.frame_loop is not None and self.model is not None else None


def read_frame_loop(acquisition: AcquisitionPart, stale_after_s: float) -> FrameLoop:
    stats = acquisition.stats
    last = stats.last_message
    return FrameLoop(
        last_message=dict(last) if last is not None else None,
        seconds_since_tracked=acquisition.seconds_since_tracked(),
        frame_rate_hz=acquisition.frame_rate_hz(stale_after_s),
        tracker_ready=acquisition.tracker is not None, model_stale=acquisition.model_stale,
        counters=Counters.of(stats), crashes=acquisition.crashes, trim=acquisition.trim.status(),
        slide=acquisition.slide.status() if acquisition.slide is not None else None)


def read_grating(grating: GratingPart, moving: bool | None, stale_after_s: float) -> Grating:
    return Grating(fresh_mm=grating.fresh_mm(stale_after_s), silent_s=grating.silent_s(), moving=moving,
                   reads=grating.reads, errors=grating.errors, crashes=grating.crashes)


def read_devices(camera: Any, stage: Any) -> Devices:
    """From the open camera and stage; a stage without a serial link counts no reconnects."""
    link_stats = getattr(getattr(stage, "link", None), "stats", None)
    low, high = stage.limits()
    return Devices(limits_mm=(low, high), camera_dropped=camera.stats.dropped,
                   stage_reconnects=getattr(link_stats, "reconnects", 0))


def job_summary(document: Mapping[str, Any]) -> dict[str, Any]:
    """The part of a job's document the status shows (the rest is at ``/api/calibration/{id}``)."""
    return {key: document[key] for key in JOB_FIELDS}
