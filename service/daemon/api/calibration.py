"""Calibration jobs: start one, follow it, read the latest."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from graytrack.service.daemon.api.deps import AUTHORIZED
from graytrack.service.daemon.api.deps import rig as get_rig
from graytrack.service.daemon.api.responses import errors
from graytrack.service.daemon.rig import Rig
from graytrack.wire import Calibration, CalibrationStarted

router = APIRouter(prefix="/api/calibration", tags=["calibration"])


@router.post("", status_code=202, dependencies=AUTHORIZED, response_model=CalibrationStarted,
             responses=errors(401, 409, 413, 503, 507))
def start_calibration(rig: Rig = Depends(get_rig)) -> CalibrationStarted:
    """Start the sweep; follow it at ``url``."""
    job = rig.start_calibration()
    return CalibrationStarted.model_validate({**job.to_dict(), "url": f"/api/calibration/{job.id}"})


@router.get("/latest", response_model=Calibration, responses=errors(404))
def latest_calibration(rig: Rig = Depends(get_rig)) -> Calibration:
    return rig.latest_calibration()


@router.get("/{calibration_id}", response_model=Calibration, responses=errors(404))
def calibration(calibration_id: str, rig: Rig = Depends(get_rig)) -> Calibration:
    return rig.calibration(calibration_id)
