"""The refusals a route documents in the OpenAPI document, each with the body it answers (``ErrorBody``)."""

from __future__ import annotations

from typing import Any

from graytrack.wire import ErrorBody

ERRORS: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorBody, "description": text}
    for status, text in ((401, "missing or invalid bearer token"), (404, "no such resource"),
                         (409, "conflicts with what the rig is doing"), (413, "request body over 64 KiB"),
                         (422, "invalid request"), (503, "the hardware is not ready or in fault"),
                         (507, "no room in the data directory for what the request would write"))
}


def errors(*statuses: int) -> dict[int | str, dict[str, Any]]:
    return {status: ERRORS[status] for status in statuses}
