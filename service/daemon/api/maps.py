"""``GET /api/maps``: the learned maps as the page draws them (the sensor's along the pixels, the print's and the
texture along the target)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, Query
from pydantic import BaseModel, Field

from graytrack.service.daemon.api.deps import rig as get_rig
from graytrack.service.daemon.api.responses import errors
from graytrack.service.daemon.errors import Invalid
from graytrack.service.daemon.maps import maps
from graytrack.service.daemon.rig import Rig
from graytrack.wire import PrintMark, SensorMark

router = APIRouter(tags=["line view"])


class SensorMapAlong(BaseModel):
    calibration: str | None
    rows: int = Field(description="the map's rows (1 for a model of one line: the rows averaged)")
    row: int | None = Field(description="the row shown; null = the rows averaged")
    pixels: int
    gain: list[float] = Field(description="each pixel's gain 1 + f (1: as calibrated)")
    gain_sigma: list[float]
    offset_gray: list[float] = Field(description="each pixel's offset e, gray (0: as calibrated)")
    offset_sigma_gray: list[float]
    touched: list[int] = Field(description="pixels something landed on")
    learned: list[int] = Field(description="pixels whose change the motion resolved")
    marks: list[SensorMark]


class PrintMapAlong(BaseModel):
    calibration: str | None
    rows: int = Field(description="the map's rows (the model's)")
    row: int | None = Field(description="the row shown; null = the rows averaged")
    node_mm: float = Field(description="the places' spacing along the target (mm)")
    x_mm: list[float] = Field(description="each place something landed on (mm, x_w); elsewhere as calibrated")
    reflectance: list[float] = Field(description="its reflectance 1 + f (1: as calibrated)")
    reflectance_sigma: list[float]
    learned: list[bool] = Field(description="its change resolved by the motion (else a candidate, set aside)")
    marks: list[PrintMark]


class TextureMarkAlong(BaseModel):
    x_mm: float
    from_mm: float
    to_mm: float
    depth: float
    depth_sigma: float | None


class TextureAlong(BaseModel):
    calibration: str | None
    marks: list[TextureMarkAlong]


class Maps(BaseModel):
    sensor_map: SensorMapAlong | None = Field(description="null: the engine keeps none, or nothing tracked yet")
    print_map: PrintMapAlong | None = Field(description="null: the engine keeps none, or nothing tracked yet")
    texture: TextureAlong | None = Field(description="null: the engine keeps none, or nothing tracked yet")
    stroke_mm: list[float] | None = Field(description="the model's stroke on the target (the print's axis)")


@router.get("/api/maps", response_model=Maps, responses=errors(422))
def learned_maps(row: int | None = Query(None, ge=0, description="one row of the maps; default the rows "
                                                                  "averaged"),
                 rig: Rig = Depends(get_rig)) -> Any:
    model = rig.model
    stroke = (float(model.stroke_range_mm[0]), float(model.stroke_range_mm[1])) if model is not None else None
    try:
        return maps(rig.acquisition, stroke, row)
    except IndexError as exc:
        raise Invalid(str(exc)) from None
