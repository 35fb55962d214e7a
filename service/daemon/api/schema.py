"""The OpenAPI document as strict as the server, where the server's limits are the rig's.

Some limits are known only to the running rig: the stage's soft limits (the configured ones
intersected with the controller's travel), the controller's top velocity, the camera's rows. A
schema that leaves them out calls a request valid that the server then refuses, and a client (or a
generated test) cannot tell a refusal it could have foreseen from a fault. So the document is
filled in from the rig each time it is asked for: ``target_mm`` between the limits in force,
``velocity_mm_s`` up to the controller's limit (and from the GCS protocol's smallest number), ``row``
below the camera's rows. What depends on the moment is described, not declared: a jog's target
(the grating position plus ``step_mm``) must lie within the soft limits, else 422, as documented.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Callable

from fastapi import FastAPI

from graytrack.service.daemon.rig import Rig
from graytrack.service.daemon.settings import Settings
from graytrack.service.daemon.stage_control import MAX_VELOCITY_MM_S


def soft_limits(rig: Rig, settings: Settings) -> tuple[float, float]:
    """The range moves are allowed in now: the controller's when it is open, else the configured one."""
    hardware = rig.hardware
    if hardware is not None:
        try:
            low, high = hardware.stage.limits()
            if math.isfinite(low) and math.isfinite(high):
                return low, high
        except Exception:  # noqa: BLE001 - a stage going away: the configured range is what is documented
            pass
    low, high = settings.hardware.stage.soft_limits_mm
    return float(low), float(high)


def top_velocity(rig: Rig) -> float:
    controller = rig.stage.velocity_limit_mm_s
    return MAX_VELOCITY_MM_S if controller is None else min(MAX_VELOCITY_MM_S, controller)


def frame_rows(rig: Rig, settings: Settings) -> int:
    """The rows of the newest frame (what ``row`` indexes), else the configured strip's."""
    acquisition = rig.acquisition
    latest = acquisition.latest if acquisition is not None else None
    if latest is not None:
        pixels = latest[0].frame.pixels
        return 1 if pixels.ndim == 1 else int(pixels.shape[0])
    return settings.hardware.camera.roi.rows


def _fill(schema: dict[str, Any], rig: Rig, settings: Settings) -> None:
    bodies = schema["components"]["schemas"]
    low, high = soft_limits(rig, settings)
    bodies["MoveRequest"]["properties"]["target_mm"].update(minimum=low, maximum=high)
    bodies["JogRequest"]["properties"]["step_mm"].update(minimum=low - high, maximum=high - low)
    bodies["VelocityRequest"]["properties"]["velocity_mm_s"]["maximum"] = top_velocity(rig)
    for parameter in schema["paths"]["/api/profile"]["get"]["parameters"]:
        if parameter["name"] == "row":
            for branch in parameter["schema"]["anyOf"]:
                if branch.get("type") == "integer":
                    branch["maximum"] = frame_rows(rig, settings) - 1


def strict_openapi(app: FastAPI, settings: Settings) -> Callable[[], dict[str, Any]]:
    """``app.openapi`` that fills the rig's limits into FastAPI's (cached) document on every request."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        schema = copy.deepcopy(generate())
        _fill(schema, app.state.rig, settings)
        return schema

    return openapi
