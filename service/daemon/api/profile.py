"""``GET /api/profile``: the line view (the latest frame, the model over it, the residual)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, Query
from pydantic import BaseModel, Field

from graytrack.service.daemon.api.deps import rig as get_rig
from graytrack.service.daemon.api.responses import errors
from graytrack.service.daemon.errors import Invalid, NotReady
from graytrack.service.daemon.profile import profile
from graytrack.service.daemon.rig import Rig

router = APIRouter(tags=["line view"])


class Profile(BaseModel):
    t: float = Field(description="mid-exposure, host monotonic s")
    frame_id: int
    rows: int
    row: int | None = Field(description="the sensor row shown; null = rows averaged")
    pixels: list[float | None] = Field(description="gray values along the pixels")
    saturation_gray: float | None
    saturated: list[int]
    bad: list[int] = Field(description="pixels the model ignores (weight 0)")
    x_mm: float | None
    locked: bool | None
    model: list[float | None] | None = Field(description="the model's gray values at x_mm")
    residual: list[float | None] | None
    sigma: list[float | None] | None = Field(description="the noise σ per pixel (gray): the residual's band")
    why_no_model: str | None


@router.get("/api/profile", response_model=Profile, responses=errors(422, 503))
def line_view(row: int | None = Query(None, ge=0, description="one sensor row; default the rows averaged"),
              rig: Rig = Depends(get_rig)) -> Any:
    try:
        document = profile(rig.acquisition, rig.model, row)
    except IndexError as exc:
        raise Invalid(str(exc)) from None
    if document is None:
        raise NotReady("no frame yet")
    return document
