"""The bodies the daemon's REST routes take and answer, shared by the daemon and its clients.

One declaration on each side of the wire: the daemon's routes name these as their request and
response models (so the OpenAPI document shows every schema), and ``graytrack.client`` parses the
answers into the same classes. This module imports pydantic, the frame record's table of
quantities and the GCS protocol's smallest number, nothing numerical and nothing of the daemon:
``import graytrack.client`` must not load numpy, and the client installs without it
(``pip install graytrack``; docs/clients.md).
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, Strict, create_model, field_validator

from graytrack.core import frame_record
from graytrack.drivers.stage.gcs_protocol import SMALLEST_NUMBER


class ErrorBody(BaseModel):  # a refusal's body (no docstring: it would become the schema's description)
    error: str = Field(description="one clear sentence")
    detail: list[dict[str, Any]] | None = None


class Health(BaseModel):
    ok: bool
    state: str
    reason: str | None = None


class Access(BaseModel):
    token_from: str = Field(description="file (the daemon wrote DATA/token at its first start) or config "
                                        "([daemon] token of its configuration)")
    token_file: str | None = Field(description="the token file's absolute path on the daemon's machine (null when "
                                               "the token comes from the configuration)")
    data_dir: str = Field(description="the daemon's data directory (the client's data_dir=)")


class Startup(BaseModel):
    step: str = Field(description="what the daemon is doing before it opens the rig")
    elapsed_s: float = Field(description="seconds in that step so far")
    expected_s: str = Field(description="how long the step takes, in words")


class JobSummary(BaseModel):
    id: str
    state: str
    progress: float
    message: str
    error: str | None = None


# The tracker's fit of a frame, one field per quantity of the frame record (core/frame_record.py):
# the same names and types as the stream's messages and the `track` CSV.
FitFigures = create_model(
    "FitFigures", __config__=ConfigDict(extra="allow"),
    **{q.name: (q.kind | None, Field(None, description=q.description))
       for q in frame_record.QUANTITIES if q.fit},
)


class ActiveCalibration(BaseModel):
    """The calibration whose model is in use, as the record has it (only ``id`` known when its row is missing)."""

    id: str
    finished: str | None = None
    model: str | None = None
    error_std_um: float | None = Field(None, description="held-out position error std (µm)")
    bound_um: float | None = Field(None, description="Cramér–Rao bound of the same frames (µm)")


class TextureMark(BaseModel):
    """A mark learned on the print (core/texture.py): where on the target, how deep, how sure."""

    x_mm: float = Field(description="its centre's target coordinate (mm)")
    from_mm: float = Field(description="the stretch of the target it covers, from (mm)")
    to_mm: float = Field(description="... to (mm)")
    depth: float = Field(description="the light it takes at its deepest node (0.3 = 30 % darker)")
    depth_sigma: float | None = Field(description="that depth's standard error (null: a node no frame saw)")
    frames: int = Field(description="frames that saw it")
    learned_at: int = Field(description="the tracker's frame at which it was learned")


class TextureStatus(BaseModel):
    """The print texture the tracker learned, part of the model of record (DATA/texture.json)."""

    calibration: str | None = Field(description="the calibration whose model it was learned with")
    marks: int = Field(description="marks learned on the print")
    footprint_scale: float = Field(description="the pixels' footprint on the print, relative to the model's")
    newest: list[TextureMark] = Field(description="the newest marks learned (at most 3)")
    saved: bool = Field(description="this state is written to DATA/texture.json")
    restored: int = Field(description="marks restored at this start from DATA/texture.json")


class SensorMark(BaseModel):
    """A mark learned on the sensor's side (core/estimator/sensor_map.py): a run of neighbouring samples of one
    row whose gain and offset the motion resolved (dust on the camera's window, a veil's edge)."""

    row: int = Field(description="the sensor row (0 for a model of one line: the rows averaged)")
    first_px: int = Field(description="its first pixel")
    last_px: int = Field(description="its last pixel")
    samples: int
    gain: float = Field(description="the light it leaves, mean over its samples (0.7 = 30 % darker)")
    gain_sigma: float = Field(description="a sample's gain's σ (RMS over the mark)")
    offset_gray: float = Field(description="light it adds (scattered), gray, mean over its samples")
    offset_sigma_gray: float = Field(description="a sample's offset's σ, gray (RMS over the mark)")


class SensorMapStatus(BaseModel):
    """The sensor's map the estimator learned, part of the model of record (DATA/sensor_map.json)."""

    calibration: str | None = Field(description="the calibration whose model it was learned with")
    touched_samples: int = Field(description="samples something landed on (set aside until resolved)")
    learned_samples: int = Field(description="of those, the samples whose change the motion resolved")
    marks: int = Field(description="marks learned (runs of learned samples along a row)")
    shown: list[SensorMark] = Field(description="the widest marks (at most 10; all: GET /api/maps)")
    saved: bool = Field(description="this state is written to DATA/sensor_map.json")
    restored: int = Field(description="marks restored at this start from DATA/sensor_map.json")


class PrintMark(BaseModel):
    """A mark learned on the print (core/estimator/print_map.py): a run of neighbouring places along the target whose
    reflectance change the motion resolved (dust settled on the print, a smudge): it moves with the stage."""

    row: int = Field(description="the model's row (0 for a model of one line)")
    first_node: int = Field(description="its first node along the row (nodes node_mm apart)")
    last_node: int = Field(description="its last node")
    nodes: int
    from_mm: float = Field(description="the stretch of the target it covers, from (mm, x_w)")
    to_mm: float = Field(description="... to (mm)")
    x_mm: float = Field(description="its centre, weighted by the light it changes (mm)")
    reflectance: float = Field(description="the light the print gives there against calibration, mean over its "
                                           "nodes (0.7 = 30 % darker)")
    reflectance_sigma: float = Field(description="a node's σ (RMS over the mark)")


class PrintMapStatus(BaseModel):
    """The print's map the estimator learned, part of the model of record (DATA/print_map.json)."""

    calibration: str | None = Field(description="the calibration whose model it was learned with")
    touched_nodes: int = Field(description="places along the target something landed on (candidates until the "
                                           "motion decides)")
    learned_nodes: int = Field(description="of those, the places carried across a pixel and resolved")
    node_mm: float = Field(description="the places' spacing along the target (a quarter of a pixel's footprint)")
    marks: int = Field(description="marks learned (runs of learned places along a row)")
    shown: list[PrintMark] = Field(description="the widest marks (at most 10; all: GET /api/maps)")
    saved: bool = Field(description="this state is written to DATA/print_map.json")
    restored: int = Field(description="marks restored at this start from DATA/print_map.json")


class TrimStatus(BaseModel):
    model_config = ConfigDict(extra="allow")  # the window's line and the followed stretch, when there are
    enabled: bool = Field(description="[daemon] trim: the online trim may correct positions")
    active: bool = Field(description="a trim is in force (its figures below; null without one)")
    scale_ppm: float | None
    scale_sigma_ppm: float | None
    offset_um: float | None
    offset_sigma_um: float | None
    drift: bool = Field(description="camera against grating drifts beyond the calibration (the scale watch)")


class TrimReset(BaseModel):
    cleared: bool = Field(description="a trim was in force and is dropped")
    trim: TrimStatus = Field(description="the trim status after the reset")


class Status(BaseModel):
    model_config = ConfigDict(extra="allow")  # later additions stay visible to clients
    state: str = Field(description="starting, idle, calibrating, tracking, fault or stopping")
    calibrated: bool
    position_mm: float | None = Field(description="null when no fresh tracked frame (older than stale_after_s)")
    locked: bool | None
    crlb_um: float | None
    fit: FitFigures | None = Field(None, description="the tracker's fit of the newest frame (null when not fresh)")
    stale: bool = Field(description="the newest figures are older than stale_after_s (withdrawn)")
    model_stale: bool = Field(False, description="the validity monitor says the model no longer holds: recalibrate")
    stale_reason: str | None = Field(
        None, description="while model_stale: the family of causes (transients, pixels, light, focus, scale, geometry)")
    age_ms: float | None
    grating_mm: float | None
    moving: bool | None = Field(description="the grating readings of the last few polls disagree")
    target_mm: float | None = Field(description="the last commanded target")
    velocity_mm_s: float | None
    reason: str | None = Field(description="every part in fault, in one sentence")
    faults: dict[str, str]
    model: str | None
    limits_mm: list[float] | None
    frame_rate_hz: float
    frames: int
    dropped: int
    calibration: JobSummary | None
    active_calibration: ActiveCalibration | None = Field(description="the calibration whose model is in use")
    texture: TextureStatus | None = Field(None, description="marks the tracker learned on the print (null: no frame "
                                                            "loop or not learning)")
    sensor_map: SensorMapStatus | None = Field(None, description="the sensor's side the estimator learned (null: the "
                                                                 "engine keeps none, or no frame loop)")
    print_map: PrintMapStatus | None = Field(None, description="the print the estimator learned (null: the engine "
                                                               "keeps none, or no frame loop)")
    simulated: bool
    startup: Startup | None = Field(None, description="while the daemon warms up before opening the rig (state "
                                                       "starting): the step and its progress; null after")
    uptime_s: float
    version: str


class Calibration(BaseModel):
    model_config = ConfigDict(extra="allow")
    id: str
    model: str
    positions: int
    frames_per_position: int
    state: str = Field(description="queued, sweeping, fitting, installing, done, failed, aborted or interrupted")
    progress: float
    message: str
    started: str
    finished: str | None = None
    duration_s: float | None = None
    error: str | None = None
    report: dict[str, Any] | None = None
    files: dict[str, str] = {}


class CalibrationStarted(Calibration):
    url: str


class MoveRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    # strict: a JSON number only (true is not 1 mm, "5" is not 5 mm)
    target_mm: Annotated[float, Strict()] = Field(
        allow_inf_nan=False, description="absolute target within the soft limits in force (the document's minimum "
                                         "and maximum, filled in from the running stage), else 422")


class JogRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    step_mm: Annotated[float, Strict()] = Field(
        allow_inf_nan=False, json_schema_extra={"not": {"const": 0}},
        description="relative move from the grating position, not 0; the target (the grating position plus the "
                    "step) must lie within the soft limits (GET /api/status limits_mm), else 422")

    @field_validator("step_mm")
    @classmethod
    def _moves(cls, value: float) -> float:
        if value == 0:
            raise ValueError("a jog of 0 mm moves nothing")
        return value


class VelocityRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    velocity_mm_s: Annotated[float, Strict()] = Field(
        allow_inf_nan=False, ge=SMALLEST_NUMBER,
        description=f"from {SMALLEST_NUMBER:g} mm/s (the smallest number the GCS protocol writes) up to the "
                    "controller's limit (the document's maximum, filled in from the running controller), else 422")


class Homed(BaseModel):
    referenced: bool


class Velocity(BaseModel):
    velocity_mm_s: float


class Moved(BaseModel):
    target_mm: float
    limits_mm: list[float]


class Stopped(BaseModel):
    stopped: bool
    aborted_calibration: str | None


class CalibrationRow(BaseModel):
    id: str
    started: str
    finished: str
    model_kind: str
    model: str | None
    error_std_um: float | None = Field(description="held-out position error std (µm)")
    bound_um: float | None = Field(description="Cramér–Rao bound of the same frames (µm)")
    frames: int | None
    effects: list[str]
    files: list[str] = Field(description="names served at /api/calibrations/{id}/files/{name}")
    summary: str | None
    active: bool = False
    damaged: str | None = Field(None, description="why this calibration's model.json cannot be read (it cannot be "
                                                  "activated); null when it reads back")


class CalibrationPage(BaseModel):
    items: list[CalibrationRow]
    total: int
    limit: int
    offset: int


class Event(BaseModel):
    id: int
    t_unix: float
    kind: str
    message: str
    details: dict[str, Any]


class Activated(BaseModel):
    active: str
    model: str
