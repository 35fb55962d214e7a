"""The stage: move within the soft limits, stop (which also aborts a calibration)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends

from graytrack.service.daemon.api.deps import AUTHORIZED
from graytrack.service.daemon.api.deps import rig as get_rig
from graytrack.service.daemon.api.responses import errors
from graytrack.service.daemon.rig import Rig
from graytrack.wire import Homed, JogRequest, MoveRequest, Moved, Stopped, Velocity, VelocityRequest

router = APIRouter(prefix="/api/stage", tags=["stage"], dependencies=AUTHORIZED)


@router.post("/move", status_code=202, response_model=Moved, responses=errors(401, 409, 413, 422, 503))
def move(request: MoveRequest, rig: Rig = Depends(get_rig)) -> Any:
    return rig.stage.move(request.target_mm)


@router.post("/stop", response_model=Stopped, responses=errors(401, 413, 503))
def stop(rig: Rig = Depends(get_rig)) -> Any:
    return rig.stage.stop()


@router.post("/jog", status_code=202, response_model=Moved, responses=errors(401, 409, 413, 422, 503))
def jog(request: JogRequest, rig: Rig = Depends(get_rig)) -> Any:
    """Move by ``step_mm`` from the current grating position (within the soft limits)."""
    return rig.stage.jog(request.step_mm)


@router.post("/home", response_model=Homed, responses=errors(401, 409, 413, 503))
def home(rig: Rig = Depends(get_rig)) -> Any:
    """The reference move; answers when the axis is referenced again."""
    return rig.stage.home()


@router.post("/velocity", response_model=Velocity, responses=errors(401, 409, 413, 422, 503))
def velocity(request: VelocityRequest, rig: Rig = Depends(get_rig)) -> Any:
    return rig.stage.set_velocity(request.velocity_mm_s)
