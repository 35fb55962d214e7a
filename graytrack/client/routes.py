"""Every REST route as data: what to send (:class:`Call`) and how to read the answer (:func:`read`).

No I/O here. The blocking and the asyncio client both send a :class:`Call` with their own HTTP
library and hand the status and body back to :func:`read`, so a route's path, body, accepted
statuses and response model are written once. Answers are parsed into the daemon's own response
models (``graytrack.wire``): the schema the OpenAPI document shows is the one
the client types with, and a field the daemon adds later stays readable (``extra="allow"``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Callable, Generic, Mapping, TypeVar
from urllib.parse import quote

from pydantic import TypeAdapter, ValidationError

from graytrack.client.errors import ProtocolError, Unreachable, for_status
from graytrack.wire import (Activated, Calibration, CalibrationPage, CalibrationRow, CalibrationStarted, Event, Health,
                            Homed, Moved, Status, Stopped, Velocity)

T = TypeVar("T")
MUTATING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
DEFAULT_TIMEOUT_S = 10.0  # one request; ``home`` answers when the reference move is done
NO_TOKEN_HINT = "this client has no token: pass token= or data_dir=, the daemon's data directory"


@dataclass(frozen=True)
class Call(Generic[T]):
    """One request and the reading of its answer."""

    method: str
    path: str
    parse: Callable[[Any], T]
    params: Mapping[str, str | int] | None = None
    body: Mapping[str, Any] | None = None
    answers: frozenset[int] = field(default=frozenset({200, 202}))  # statuses whose body is the result
    raw: bool = False  # the result is parsed from the body's bytes, not from JSON (files, metrics)

    @property
    def needs_token(self) -> bool:
        return self.method in MUTATING

    def __str__(self) -> str:
        return f"{self.method} {self.path}"


def _model(model: type[Any]) -> Callable[[Any], Any]:
    return model.model_validate


def _finite(name: str, value: float) -> float:
    """A JSON number for the body: refused here when JSON cannot carry it or it is not a number at all."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return float(value)


def _segment(text: str) -> str:
    return quote(str(text), safe="")


def status() -> Call[Status]:
    return Call("GET", "/api/status", _model(Status))


def health() -> Call[Health]:
    # 503 is an answer here, not a failure: its body says why the daemon is not measuring
    return Call("GET", "/healthz", _model(Health), answers=frozenset({200, 503}))


def start_calibration() -> Call[CalibrationStarted]:
    return Call("POST", "/api/calibration", _model(CalibrationStarted))


def calibration(calibration_id: str = "latest") -> Call[Calibration]:
    return Call("GET", f"/api/calibration/{_segment(calibration_id)}", _model(Calibration))


def calibrations(limit: int = 20, offset: int = 0) -> Call[CalibrationPage]:
    return Call("GET", "/api/calibrations", _model(CalibrationPage), params={"limit": limit, "offset": offset})


def calibration_row(calibration_id: str) -> Call[CalibrationRow]:
    return Call("GET", f"/api/calibrations/{_segment(calibration_id)}", _model(CalibrationRow))


def activate(calibration_id: str) -> Call[Activated]:
    return Call("POST", f"/api/calibrations/{_segment(calibration_id)}/activate", _model(Activated))


_EVENTS = TypeAdapter(list[Event])


def events(since: int | str | datetime = 0, limit: int = 200) -> Call[list[Event]]:
    """Events after ``since``: an event id (the last one seen) or a time (an aware datetime or ISO 8601 text)."""
    mark = since.isoformat() if isinstance(since, datetime) else str(since)
    return Call("GET", "/api/events", _EVENTS.validate_python, params={"since": mark, "limit": limit})


def move(target_mm: float) -> Call[Moved]:
    return Call("POST", "/api/stage/move", _model(Moved), body={"target_mm": _finite("target_mm", target_mm)})


def jog(step_mm: float) -> Call[Moved]:
    return Call("POST", "/api/stage/jog", _model(Moved), body={"step_mm": _finite("step_mm", step_mm)})


def stop() -> Call[Stopped]:
    return Call("POST", "/api/stage/stop", _model(Stopped))


def home() -> Call[Homed]:
    return Call("POST", "/api/stage/home", _model(Homed))


def set_velocity(velocity_mm_s: float) -> Call[Velocity]:
    return Call("POST", "/api/stage/velocity", _model(Velocity),
                body={"velocity_mm_s": _finite("velocity_mm_s", velocity_mm_s)})


def calibration_file(calibration_id: str, name: str) -> Call[bytes]:
    """``report.html``, ``report.json``, ``model.json`` or ``recording.npz`` of a finished calibration."""
    return Call("GET", f"/api/calibrations/{_segment(calibration_id)}/files/{_segment(name)}", bytes, raw=True)


def reset_trim() -> Call[dict[str, Any]]:
    return Call("POST", "/api/trim/reset", dict)


def profile(row: int | None = None) -> Call[dict[str, Any]]:
    """The line view (``GET /api/profile``): the latest frame along the pixels against the model."""
    return Call("GET", "/api/profile", dict, params=None if row is None else {"row": row})


def maps(row: int | None = None) -> Call[dict[str, Any]]:
    """The learned maps (``GET /api/maps``): the sensor's along the pixels, the print's along the target."""
    return Call("GET", "/api/maps", dict, params=None if row is None else {"row": row})


def metrics() -> Call[str]:
    return Call("GET", "/metrics", lambda content: content.decode("utf-8"), raw=True)


def headers(call: Call[Any], token: str | None) -> dict[str, str] | None:
    """The bearer token goes with every request when the client has one: state changes need it, and so do
    reads from a daemon bound beyond loopback (``[daemon] read_token``); in a header, never in the URL."""
    return {"Authorization": f"Bearer {token}"} if token else None


def unreachable(call: Call[Any], url: str, exc: Exception) -> Unreachable:
    return Unreachable(f"{type(exc).__name__}: {exc}".rstrip(": "), request=f"{call} at {url}")


def read(call: Call[T], status: int, content: bytes, has_token: bool = True) -> T:
    """The result of ``call`` from its answer, or the exception for the daemon's refusal."""
    if status in call.answers and call.raw:
        return call.parse(content)
    try:
        document = json.loads(content) if content else None
    except ValueError:
        document = None
    if status in call.answers:
        if document is None:
            raise ProtocolError(f"answered {status} without a JSON body", status, str(call))
        try:
            return call.parse(document)
        except (ValidationError, TypeError, ValueError) as exc:
            first = str(exc).splitlines()[0]
            raise ProtocolError(f"answer not in the daemon's schema: {first}", status, str(call)) from None
    error = document.get("error") if isinstance(document, dict) else None
    if not isinstance(error, str):
        error = content[:200].decode("utf-8", "replace").strip() or "no reason given"
    hint = NO_TOKEN_HINT if status == 401 and not has_token else None
    raise for_status(status, error, str(call), hint)
