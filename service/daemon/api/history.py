"""The record: calibrations (newest first, with their files) and the event log; rolling back a model."""

from __future__ import annotations

import re
from datetime import datetime
from typing import Any

from fastapi import APIRouter, Depends, Query
from fastapi.responses import FileResponse

from graytrack.service.daemon.api.deps import AUTHORIZED
from graytrack.service.daemon.api.deps import rig as get_rig
from graytrack.service.daemon.api.responses import errors
from graytrack.service.daemon.errors import Invalid, NotFound
from graytrack.service.daemon.rig import Rig
from graytrack.wire import Activated, CalibrationPage, CalibrationRow, Event

router = APIRouter(tags=["record"])
MAX_ROW_ID = 2**63 - 1  # SQLite's integers are 64-bit: a larger id or offset names no row
FILES = {"report.html": "text/html", "report.json": "application/json", "model.json": "application/json",
         "recording.npz": "application/octet-stream"}


@router.get("/api/calibrations", response_model=CalibrationPage)
def calibrations(limit: int = Query(20, ge=1, le=500), offset: int = Query(0, ge=0, le=MAX_ROW_ID),
                 rig: Rig = Depends(get_rig)) -> CalibrationPage:
    """Calibrations that finished ``done``, newest first; one whose model file cannot be read back says why
    in ``damaged``."""
    items, total = rig.history.calibrations(limit, offset)
    active = rig.storage.active_id()
    return CalibrationPage(items=[_row(item, active, rig) for item in items], total=total, limit=limit, offset=offset)


def _row(row: dict[str, Any], active: str | None, rig: Rig) -> CalibrationRow:
    """A record's row as the API shows it, marked when its model is the one in use or is damaged."""
    return CalibrationRow.model_validate({**row, "active": row["id"] == active, "damaged": rig.damage(row["id"])})


@router.get("/api/calibrations/{calibration_id}", response_model=CalibrationRow, responses=errors(404))
def calibration_row(calibration_id: str, rig: Rig = Depends(get_rig)) -> CalibrationRow:
    row = rig.history.calibration(calibration_id)
    if row is None:
        raise NotFound(f"no finished calibration {calibration_id!r}")
    return _row(row, rig.storage.active_id(), rig)


@router.get("/api/calibrations/{calibration_id}/files/{name}", response_class=FileResponse, responses=errors(404))
def calibration_file(calibration_id: str, name: str, rig: Rig = Depends(get_rig)) -> FileResponse:
    """``report.html``, ``report.json``, ``model.json`` or ``recording.npz`` of a finished calibration."""
    row = rig.history.calibration(calibration_id)
    if row is None or name not in FILES or name not in row["files"]:
        raise NotFound(f"no file {name!r} in calibration {calibration_id!r}")
    path = rig.storage.calibration_dir(calibration_id) / name
    if not path.is_file():
        raise NotFound(f"{name} of calibration {calibration_id} is gone from the data directory")
    disposition = "inline" if name.startswith("report") else "attachment"
    # the closed loop's report styles itself inline; it runs no script either way
    headers = {"Content-Security-Policy": "default-src 'none'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
                                          "frame-ancestors 'none'; base-uri 'none'; form-action 'none'"}
    return FileResponse(path, media_type=FILES[name], filename=f"{calibration_id}-{name}",
                        content_disposition_type=disposition, headers=headers)


@router.post("/api/calibrations/{calibration_id}/activate", dependencies=AUTHORIZED, response_model=Activated,
             responses=errors(401, 404, 409, 413, 503, 507))
def activate(calibration_id: str, rig: Rig = Depends(get_rig)) -> Activated:
    """Track with that calibration's model from now on (and after restarts). 409 when a calibration runs, or
    when this one's ``model.json`` is damaged (missing, not JSON, another schema: the answer names the file)."""
    return rig.activate(calibration_id)


EVENT_ID = re.compile(r"[0-9]{1,18}")  # ASCII digits only ("²" is a digit to str.isdigit); below 2^63
FIRST_YEAR = 1970  # times are Unix times in the record: none before
SINCE_SCHEMA = {"anyOf": [{"pattern": f"^{EVENT_ID.pattern}$"},
                          {"format": "date-time", "pattern": "^(19[7-9][0-9]|[2-9][0-9]{3})-"}]}


@router.get("/api/events", response_model=list[Event], responses=errors(422))
def events(since: str = Query("0", description=f"an event id (the last one seen, at most 18 digits) or an ISO 8601 "
                                               f"time from {FIRST_YEAR} on; anything else is 422",
                              json_schema_extra=SINCE_SCHEMA),
           limit: int = Query(200, ge=1, le=500), rig: Rig = Depends(get_rig)) -> list[Event]:
    """Events after ``since``, oldest first."""
    if EVENT_ID.fullmatch(since):
        return _events(rig.history.events(since_id=int(since), limit=limit))
    wrong = f"since={since[:40]!r}: give an event id (at most 18 digits) or an ISO 8601 time from {FIRST_YEAR} on"
    try:
        moment = datetime.fromisoformat(since.replace("Z", "+00:00"))
        if moment.year < FIRST_YEAR:  # the year as written, as the schema's pattern reads it
            raise Invalid(wrong)
        if moment.tzinfo is None:
            moment = moment.astimezone()
        since_unix = moment.timestamp()
    except (ValueError, OverflowError, OSError):  # not a time, or one the platform cannot place
        raise Invalid(wrong) from None
    return _events(rig.history.events(since_unix=since_unix, limit=limit))


def _events(rows: list[dict[str, Any]]) -> list[Event]:
    return [Event.model_validate(row) for row in rows]
