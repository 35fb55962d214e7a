"""``POST /api/trim/reset``: drop the online trim (token); drift is measured against calibration again."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from graytrack.service.daemon.api.deps import AUTHORIZED
from graytrack.service.daemon.api.deps import rig as get_rig
from graytrack.service.daemon.api.responses import errors
from graytrack.service.daemon.errors import NotReady
from graytrack.service.daemon.rig import Rig
from graytrack.wire import TrimReset

router = APIRouter(prefix="/api/trim", tags=["trim"], dependencies=AUTHORIZED)


@router.post("/reset", response_model=TrimReset, responses=errors(401, 413, 503))
def reset(rig: Rig = Depends(get_rig)) -> TrimReset:
    """``{"cleared": bool, "trim": {...}}``: whether a trim was in force, and the trim status after."""
    acquisition = rig.acquisition
    if acquisition is None:
        raise NotReady("the frame loop is not running")
    cleared = acquisition.trim.reset("on request (POST /api/trim/reset)")
    return TrimReset(cleared=cleared, trim=acquisition.trim.status())
