"""``/healthz``, ``/api/status`` and ``/metrics``: what the daemon is doing, as of now."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse, PlainTextResponse

from graytrack.core.validity import ADVICE
from graytrack.service.daemon import metrics
from graytrack.service.daemon.api.deps import rig as get_rig
from graytrack.service.daemon.rig import Rig
from graytrack.wire import Health, Status

router = APIRouter(tags=["status"])


@router.get("/healthz", response_model=Health,
            responses={503: {"model": Health,
                             "description": "not tracking now, or the model is stale: the reason says"}})
def healthz(rig: Rig = Depends(get_rig)) -> Any:
    """200 while frames are being tracked now; 503 otherwise (starting, idle, fault, stale), with the reason."""
    snapshot = rig.snapshot()
    fresh, state = snapshot.tracking_fresh, snapshot.state
    stale = snapshot.model_stale if fresh else None
    body = {"ok": fresh and stale is None, "state": state, "reason": None}
    if not fresh:
        body["reason"] = snapshot.reason or ("frames are not being tracked" if state != "idle"
                                             else "no model installed: calibrate first")
        return JSONResponse(body, status_code=503)
    if stale is not None:
        body["reason"] = f"the model is stale (cause: {stale}): {ADVICE[stale]}"
        return JSONResponse(body, status_code=503)
    return body


@router.get("/api/status", response_model=Status)
def status(request: Request, rig: Rig = Depends(get_rig)) -> Any:
    """The status document of this instant (one snapshot of the rig, ``service/daemon/status.py``), with the
    warm-up's step while the daemon is starting (``service/daemon/startup.py``)."""
    return {**rig.status(), "startup": request.app.state.startup.status()}


@router.get("/metrics", response_class=PlainTextResponse)
def prometheus(request: Request) -> PlainTextResponse:
    """Counters and gauges in the Prometheus text format."""
    return PlainTextResponse(metrics.render(request.app.state.rig.snapshot(), request.app.state.broadcaster,
                                             request.app.state.limits),
                             media_type=metrics.CONTENT_TYPE)
