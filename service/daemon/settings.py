"""The daemon's configuration file: ``[camera]``/``[stage]`` (drivers.config) plus ``[daemon]`` and ``[sweep]``.

One TOML file configures everything (``deploy/graytrack.example.toml``). The hardware tables are
validated by the drivers' own strict models; the two tables owned here are just as strict, and an
unknown top-level table is an error too, because a misspelt ``[sweeep]`` on a bench would
otherwise calibrate with defaults nobody chose. Every error names its key.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, NonNegativeInt, ValidationError, model_validator

from graytrack.drivers.config import (ConfigError, HardwareConfig, StrictTable, describe_validation_error, load_toml,
                                      parse_hardware)
from graytrack.drivers.realtime import DEFAULT_LEVEL
from graytrack.drivers.registry import stages
from graytrack.service.daemon.loss_log import QUIET_S as LOSS_QUIET_S

DEFAULT_HOST = "127.0.0.1"  # docs/contracts.md: loopback unless told otherwise
DEFAULT_PORT = 8000


class DaemonConfig(StrictTable):
    host: str = DEFAULT_HOST
    port: int = Field(DEFAULT_PORT, ge=0, le=65535)
    data_dir: str | None = Field(None, description="models, calibrations, token; default: see default_data_dir()")
    token: str | None = Field(None, min_length=16, description="bearer token; omitted = generated into data_dir")
    auto_calibrate: Literal["sim", "always", "never"] = Field(
        "sim", description="calibrate at start when no model is saved: only on the virtual rig, always, never")
    camera_fault_after_s: float = Field(2.0, gt=0, description="no frame for this long = camera fault")
    reopen_interval_s: float = Field(2.0, gt=0, description="wait between attempts to reopen failed hardware")
    grating_poll_s: float = Field(0.005, gt=0, description="wall time between POS? reads of the grating poller")
    pair_window_s: float = Field(0.02, gt=0, description="host seconds: the widest gap between the two grating "
                                                         "readings a frame is interpolated between")
    pair_tolerance_um: float = Field(1.0, gt=0, description="largest interpolation error a paired reference may have "
                                                           "(acceleration between readings); else none is sent")
    pair_change_mm_s2: float = Field(200.0, gt=0, description="the largest change of acceleration the stage makes "
                                     "between two readings (a reversal: its ACC plus its DEC); a frame with readings "
                                     "on one side only is paired only while this cannot bend the line past the "
                                     "tolerance")
    pair_rest_s: float = Field(0.25, gt=0, description="host seconds the newest grating reading of a stage at rest "
                                                       "(no command since) stands for")
    stale_after_s: float = Field(0.5, gt=0, description="a position or rate older than this is withdrawn (null)")
    frames_lost_quiet_s: float = Field(LOSS_QUIET_S, gt=0, description="host seconds: frames lost within this of the "
                                       "last frames_lost event are summed into the next one, so a frame loop that "
                                       "keeps falling behind writes a few events a minute, not one per frame (the "
                                       "event log keeps every kind's newest, and a flood would push the rest out)")
    read_token: Literal["beyond_loopback", "always", "never"] = Field(
        "beyond_loopback", description="when reads (status, profile, events, calibrations and their files, metrics, "
        "the stream) need the bearer token: when the daemon listens beyond loopback, always, or never; the page, "
        "its files, /healthz and /api/access stay open (api/read_policy.py)")
    allowed_origins: list[str] = Field(default_factory=list,
                                       description="WebSocket Origins accepted besides the page's own")
    allowed_hosts: list[str] = Field(default_factory=list,
                                     description="Host names accepted besides the bind address and "
                                                 "loopback names (DNS rebinding guard)")
    ws_compression: bool = Field(False, description="permessage-deflate on WebSockets: fewer bytes on a slow link, "
                                 "but one zlib compression per message and client on the event loop (at 1 kHz the "
                                 "stream's largest loop cost and its latency tail)")
    max_connections: int = Field(256, ge=1, le=100_000, description="open HTTP and WebSocket connections served at "
                                 "once; beyond it a request gets 503 and a WebSocket is closed 1013, both with the "
                                 "reason (each open connection costs a file descriptor and some memory)")
    max_connections_per_client: int = Field(32, ge=1, le=100_000, description="open connections from one client "
                                            "(its address; IPv6: its /64) served at once, so one client cannot take "
                                            "them all (a browser opens 6 per site); beyond it the same answers as "
                                            "beyond max_connections")
    requests_per_s_per_client: float = Field(200.0, gt=0, le=1e6, description="requests one client may begin per "
                                             "second (a second's worth at once); beyond, its next request waits, "
                                             "unread (one client cannot take the others' turns)")
    requests_per_s: float = Field(500.0, gt=0, le=1e6, description="requests all clients together may begin per "
                                  "second (a second's worth at once); beyond, the next requests wait, unread (a "
                                  "flood from many clients slows the answers, not the frame loop)")
    serving_share: float = Field(0.25, gt=0, le=1.0, description="the share of one core (CPU seconds per second, "
                                 "measured) that serving clients may take: the event loop and the request threads, the "
                                 "stream's deliveries apart; beyond, the next request waits, unread. The frame loop "
                                 "and the stage link share one interpreter with serving: a quarter leaves them the "
                                 "rest of it, whatever a request costs. A frame the rig loses cuts the share in "
                                 "force by half (to an eighth at least), grown back over 10 s without a loss: the "
                                 "rig first on a host slower than this share assumes")
    request_timeout_s: float = Field(10.0, gt=0, le=3600, description="a request (head and body) must arrive whole "
                                     "within this of its first byte, a new connection send one within this: else "
                                     "408 and closed (slow or idle clients cannot hold connections); a client "
                                     "that takes none of its answers for this long is closed too")
    keep_alive_s: float = Field(5.0, gt=0, le=3600, description="an idle connection between requests is closed "
                                "after this")
    api_docs: bool = Field(False, description="serve the interactive API docs at /api/docs (loads scripts from a CDN)")
    realtime_priority: int = Field(DEFAULT_LEVEL, ge=0, le=99,
                                   description="SCHED_FIFO priority of the frame loop, the event "
                                   "loop and the grating poller (1-99; needs LimitRTPRIO or CAP_SYS_NICE): the "
                                   "stream's latency tail on a busy machine. "
                                   "0 = normal scheduling")
    cpu_cores: list[NonNegativeInt] = Field(default_factory=list,
                                            description="cores the daemon's threads run on (empty: "
                                 "wherever the kernel puts them). One core of its own: its threads share one "
                                 "interpreter lock anyway, and pinned they stop handing it across cores and being "
                                 "preempted by other processes while they hold it; the virtual rig's process then "
                                 "runs on the others. Cores this process may not use are refused in the log")
    trim: bool = Field(False, description="correct the streamed position's scale and offset against the grating "
                       "(an online trim, only on evidence of a drift since calibration; POST /api/trim/reset clears "
                       "it, a new calibration too)")
    grating: bool = Field(True, description="the stage's position readout (POS?) is a grating the frames are paired "
                          "with; false: the rig has none (an open-loop stage): frames are tracked and streamed without "
                          "it, and each bound carries the slide a magnification change could give the image "
                          "(slide_sigma_um, in crlb_um; service/daemon/slide.py)")
    axis_px: float | None = Field(None, ge=0, description="without a grating: the optical axis's distance from the "
                                  "ROI's centre along the line, pixels, the slide's lever (unset: 300, a prior; 0: the "
                                  "ROI on the axis, nothing carried)")
    stage_acceleration_mm_s2: float | None = Field(
        None, gt=0, description="without a grating, with engine = estimator: the most the stage accelerates (its "
        "ACC/DEC); a step of the image against the carriage beyond what such a motion makes over four frames is "
        "the camera moving on its mount, flagged and carried in the bound (core/estimator/mount.py). Unset: the "
        "estimator's declared default, or more where the calibration's readout showed the stage faster")
    mains_hz: float | None = Field(
        None, ge=0, description="with engine = estimator: the mains frequency the rig's lamp runs on (Hz: 60 where the "
        "grid is, 0 a lamp on DC), whose flicker at twice it the estimator follows; written into the daemon's "
        "recordings as meta.mains_hz. Unset: the estimator's declared default (50)")
    stage_commanded_here: bool = Field(
        True, description="with engine = estimator: every motion of the stage is commanded through this daemon (REST "
        "moves, jogs, homing, velocity changes, stops, the calibration sweep), so the stage's most acceleration is "
        "allowed only from a command until its readings show it at rest again: between commands the estimator's "
        "stage holds its path (its velocity carried from frame to frame, unless the grating is fused) and, without "
        "a grating, a step of the image while it rests or cruises is the camera's mount far sooner "
        "(service/daemon/motion.py); false: something else also drives the stage, and its most is allowed "
        "throughout")
    engine: Literal["watches", "estimator"] = Field(
        "watches", description="the per-frame path: today's solver and its watches, or the one recursive estimator "
        "being built to replace it (core/estimator/: every nuisance a state with a declared rate, the bound its "
        "posterior, flags from one innovation test; with trim = true it fuses the grating, with grating = false "
        "it reads none; it learns no print texture yet)")
    events_max_age_days: float = Field(90.0, gt=0, description="the event log keeps events this long (the newest "
                                       "of each kind always)")
    events_max_count: int = Field(100_000, ge=10, description="and at most this many (about 140 bytes each), "
                                  "besides the newest of each kind")
    sim_clock_scale: float = Field(1.0, gt=0, description="virtual rig only: simulated seconds per wall second")
    log_level: Literal["debug", "info", "warning", "error"] = "info"

    @model_validator(mode="after")
    def _trim_needs_a_grating(self) -> "DaemonConfig":
        """A trim against a grating the rig does not have would never act: said now, not silently ignored."""
        if self.trim and not self.grating:
            raise ValueError("trim = true needs a grating (grating = false: nothing to trim against)")
        return self


class SweepConfig(StrictTable):
    kind: Literal["stops", "scan"] = Field("stops", description="stops: step and settle at `positions` stops; scan: "
                                           "frames at rest at both ends and a pass up and one down at constant "
                                           "velocity, every frame with its interpolated grating reference (frames in "
                                           "motion at ±v: what a timing error of the grating shows in)")
    scan_frames: int = Field(1000, ge=50, le=100_000, description="scan: frames the pass should record; its velocity "
                                                                   "follows from the frame rate (at most the stage's)")
    positions: int = Field(41, ge=2, description="stops: step-and-settle stops over the soft limits")
    # three frames at one stop are what the model-free noise estimate (second differences in time) needs
    frames_per_position: int = Field(5, ge=3, description="frames at each stop (scan: at each end)")
    margin_mm: float = Field(0.1, ge=0, description="keep this far inside the soft limits")
    settle_timeout_s: float = Field(10.0, gt=0)
    # a stop is checked where it settled: something else commanding the stage (another program on the
    # controller, a move that slipped in) is then a failed sweep with the cause, not a model fitted on a
    # stop recorded somewhere else. Ten times the settle window a PI controller reports on target in.
    stop_tolerance_um: float = Field(10.0, gt=0, description="largest distance between a stop's planned and "
                                                              "settled position (µm), else the sweep fails")
    frame_timeout_s: float = Field(5.0, gt=0, description="wall time to wait for the frames of one stop")
    model: Literal["paper", "auto"] = Field("auto", description="auto = the closed loop (finds the effects the rig "
                                            "has), or the paper model")
    pixel_pitch_mm: float | None = Field(None, gt=0, description="nominal alpha*d for real hardware (else estimated)")
    period_mm: float | None = Field(None, gt=0, description="nominal target period for real hardware (else estimated)")


class Settings(StrictTable):
    hardware: HardwareConfig = HardwareConfig()
    daemon: DaemonConfig = DaemonConfig()
    sweep: SweepConfig = SweepConfig()

    @property
    def simulated(self) -> bool:
        """The virtual rig runs (a simulated stage: its driver says so, drivers/registry.py)."""
        return stages.resolve(self.hardware.stage.kind).simulated

    def data_path(self) -> Path:
        return Path(self.daemon.data_dir) if self.daemon.data_dir else default_data_dir()

    def with_overrides(self, **daemon: Any) -> "Settings":
        """Command-line flags win over the file (``None`` = not given)."""
        changes = {key: value for key, value in daemon.items() if value is not None}
        return self.model_copy(update={"daemon": self.daemon.model_copy(update=changes)})


OWN_TABLES = {"daemon": DaemonConfig, "sweep": SweepConfig}
HARDWARE_TABLES = ("camera", "stage")


def default_data_dir() -> Path:
    """systemd's ``StateDirectory`` when run as the unit, else the XDG state directory."""
    if os.environ.get("STATE_DIRECTORY"):
        return Path(os.environ["STATE_DIRECTORY"].split(":")[0])
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "graytrack"


def parse_settings(tables: dict[str, Any]) -> Settings:
    unknown = sorted(set(tables) - set(OWN_TABLES) - set(HARDWARE_TABLES))
    if unknown:
        raise ConfigError(f"{unknown[0]}: unknown table (expected camera, stage, daemon, sweep)")
    hardware = parse_hardware(tables)
    parts: dict[str, Any] = {"hardware": hardware}
    for name, model in OWN_TABLES.items():
        try:
            parts[name] = model.model_validate(tables.get(name, {}))
        except ValidationError as exc:
            raise ConfigError("; ".join(f"{name}.{describe_validation_error(error)}"
                                        for error in exc.errors())) from None
    return Settings(**parts)


def load_settings(path: str | os.PathLike[str] | None) -> Settings:
    """The file's settings, or the embedded default (the virtual rig) when ``path`` is None."""
    if path is None:
        return Settings()
    return load_toml(path, parse_settings)
