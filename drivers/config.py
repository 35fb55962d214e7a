"""Configuration of the camera and the stage controller: the ``[camera]`` and ``[stage]`` tables.

The daemon reads one TOML file (see ``deploy/graytrack.example.toml``); these models own the two
hardware tables and ignore the others. Unknown keys are errors, not silently ignored, because a
misspelt ``exposure_us`` on a bench would otherwise run with the camera's default. Every error
names its key, e.g. ``stage.soft_limits_mm: low must be below high``.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Callable, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from graytrack.drivers.camera.backlog import DEFAULT_MAX_LAG_S
from graytrack.drivers.camera.base import CameraSettings, Roi

STANDARD_BAUD_RATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800)


ParsedT = TypeVar("ParsedT")


class ConfigError(ValueError):
    """A configuration file or table that cannot be used; the message names the key."""


class StrictTable(BaseModel):
    """A configuration table: an unknown key is an error (a typo is never silently ignored), and the
    values are fixed once read."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class RoiConfig(StrictTable):
    row: int = Field(0, ge=0, description="first sensor row of the strip")
    rows: int = Field(1, ge=1, description="rows in the strip")
    col: int = Field(0, ge=0, description="first pixel column")
    cols: int | None = Field(None, ge=2, description="pixels per row; omitted = to the sensor's right edge")

    def to_roi(self) -> Roi:
        return Roi(self.row, self.rows, self.col, self.cols)


def _registered(registry_name: str) -> Callable[[str], str]:
    """A validator of ``kind``: the name of a registered driver (drivers/registry.py), read back as that
    driver's short name, so "OpenCVCamera" and "opencv" configure the same camera."""
    def check(value: str) -> str:
        from graytrack.drivers import registry  # (imports the drivers: only when a table is validated)

        try:
            return getattr(registry, registry_name).resolve(value).name
        except LookupError as exc:
            raise ValueError(str(exc)) from None
    return check


class CameraConfig(StrictTable):
    kind: str = Field("sim", description="the camera's driver: its class (OpenCVCamera, AravisCamera, SimCamera), "
                                         "dotted path or short name (opencv, aravis, sim)")
    device: str | int | None = Field(None, description="opencv: index, file or URL; aravis: device id or IP")
    roi: RoiConfig = RoiConfig()
    exposure_us: float | None = Field(None, gt=0)
    gain_db: float | None = None
    frame_rate_hz: float | None = Field(None, gt=0)
    readout_us: float = Field(0.0, ge=0, description="opencv, aravis: exposure end to frame hand-over, "
                                                     "subtracted with half the exposure to stamp mid-exposure")
    trigger: Literal["free-run", "software", "hardware"] = "free-run"
    trigger_source: str = "Line0"
    pixel_format: Literal["Mono8", "Mono10", "Mono12", "Mono16"] = "Mono8"
    n_buffers: int = Field(8, ge=2, le=256)
    max_lag_ms: float = Field(DEFAULT_MAX_LAG_S * 1e3, ge=0, le=1000,
                              description="a read hands out frames in order while the oldest waiting is within this "
                                          "of the newest; older ones are skipped (dropped). 0 = newest only")
    timeout_s: float = Field(1.0, gt=0)
    flip: bool = Field(False, description="reverse the pixel axis of every frame (a camera mounted the other way "
                                          "round: increasing column must be increasing target coordinate)")
    scenario: str = Field("paper", description="sim: the virtual rig's scenario")
    effects: str = Field("", description="sim: effects the virtual rig has besides its scenario's, as "
                                         "`graytrack simulate --effects` takes them (e.g. \"dust:count=6,flicker\")")
    seed: int = 0
    rig_process: bool = Field(True,
                              description="sim: run the virtual rig (the stage's motion, the simulated controller "
                                          "and the camera's rendering) in a process of its own, out of the "
                                          "daemon's interpreter; the same frames either way")

    _known_kind = field_validator("kind")(_registered("cameras"))

    @model_validator(mode="after")
    def _rig_exists(self) -> "CameraConfig":
        """A virtual rig that cannot be built is a configuration error now, not a fault at start."""
        if self.kind == "sim":
            from graytrack.drivers.sim.scenarios import build_config

            build_config(self.scenario, self.effects, seed=self.seed)  # ValueError naming the scenario or effect
        return self

    @model_validator(mode="after")
    def _device_where_needed(self) -> "CameraConfig":
        if self.kind == "opencv" and self.device is None:
            raise ValueError("device is required for kind = 'opencv' (an index, a video file or a URL)")
        if self.kind != "aravis" and self.trigger != "free-run":
            raise ValueError(f"trigger '{self.trigger}' needs kind = 'aravis'")
        return self

    def to_settings(self) -> CameraSettings:
        return CameraSettings(self.exposure_us, self.gain_db, self.frame_rate_hz, self.roi.to_roi(),
                              max_lag_s=self.max_lag_ms * 1e-3, flip=self.flip)


class StageConfig(StrictTable):
    kind: str = Field("sim", description="the stage's driver: its class (GCSStage, SimGCSController), dotted path "
                                         "or short name (gcs, sim)")
    port: str | None = Field(None, description="gcs: serial device, e.g. /dev/serial/by-id/usb-PI_...")
    baudrate: int = 115200
    axis: str = Field("1", pattern=r"^[A-Za-z0-9_]+$")
    soft_limits_mm: tuple[float, float] = (0.0, 10.46)
    velocity_mm_s: float | None = Field(None, gt=0)
    timeout_s: float = Field(1.0, gt=0)
    reference_on_open: bool = True

    _known_kind = field_validator("kind")(_registered("stages"))

    @field_validator("baudrate")
    @classmethod
    def _standard_baud(cls, value: int) -> int:
        if value not in STANDARD_BAUD_RATES:
            raise ValueError(f"must be one of {', '.join(map(str, STANDARD_BAUD_RATES))}")
        return value

    @field_validator("soft_limits_mm")
    @classmethod
    def _ordered(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not value[0] < value[1]:
            raise ValueError("low must be below high")
        return value

    @model_validator(mode="after")
    def _port_where_needed(self) -> "StageConfig":
        if self.kind == "gcs" and not self.port:
            raise ValueError("port is required for kind = 'gcs'")
        return self


class HardwareConfig(StrictTable):
    camera: CameraConfig = CameraConfig()
    stage: StageConfig = StageConfig()


def parse_hardware(tables: dict[str, Any]) -> HardwareConfig:
    """Validate the ``camera`` and ``stage`` tables of a parsed TOML document (others ignored)."""
    try:
        return HardwareConfig.model_validate({k: v for k, v in tables.items() if k in ("camera", "stage")})
    except ValidationError as exc:
        raise ConfigError("; ".join(describe_validation_error(error) for error in exc.errors())) from None


def read_toml(path: Path) -> dict[str, Any]:
    """A TOML file's tables; a missing or malformed file is a :class:`ConfigError` naming it."""
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML "
                          f"(not UTF-8 text: byte {exc.start} is {exc.object[exc.start]:#04x})") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML (nested too deeply to read)") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a TOML file") from None


def load_toml(path: str | Path, parse: Callable[[dict[str, Any]], ParsedT]) -> ParsedT:
    """Read a TOML file and validate it with ``parse``; every error names the file."""
    path = Path(path)
    tables = read_toml(path)
    try:
        return parse(tables)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def load_hardware(path: str | Path) -> HardwareConfig:
    return load_toml(path, parse_hardware)


def describe_validation_error(error: Any) -> str:
    """One pydantic error as ``table.key: message`` ("unknown key" for a key the model forbids)."""
    key = ".".join(str(part) for part in error["loc"])
    message = error["msg"].removeprefix("Value error, ")
    if error["type"] == "extra_forbidden":
        message = "unknown key"
    return f"{key}: {message}" if key else message
