"""The OpenAPI document says what the server does (issue #38, item 7): bodies it cannot read are the
documented 422, a 405 names the methods allowed, and in each place where the server refused a
request its own schema called valid, the schema now refuses it too (and accepts what the server
accepts), with the rig's run-time limits filled in (service/daemon/api/schema.py)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import jsonschema
import pytest

from graytrack.service.daemon.app import create_app
from tests.service.helpers import LiveServer, fast_settings


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory, calibrated) -> Iterator[LiveServer]:
    with LiveServer(create_app(fast_settings(calibrated(tmp_path_factory.mktemp("schema"))))) as server:
        server.wait_state("tracking")
        yield server


@pytest.fixture(scope="module")
def document(daemon: LiveServer) -> dict[str, Any]:
    return daemon.get("/api/openapi.json").json()


def _valid(document: dict[str, Any], schema: dict[str, Any], value: Any) -> bool:
    resolver = {"components": document["components"], **schema}
    return jsonschema.Draft202012Validator(resolver).is_valid(value)


def _body(document: dict[str, Any], name: str) -> dict[str, Any]:
    return document["components"]["schemas"][name]


def _parameter(document: dict[str, Any], path: str, name: str) -> dict[str, Any]:
    return next(p["schema"] for p in document["paths"][path]["get"]["parameters"] if p["name"] == name)


@pytest.mark.parametrize("body, reason", [
    (b"\xff", "not UTF-8"),
    (b"[" * 5000 + b"]" * 5000, "nested too deeply"),
    (b'{"target_mm": ' + b"1" * 5000 + b"}", "an integer over 4300 digits"),
])
def test_a_body_that_cannot_be_read_is_the_documented_422(daemon: LiveServer, document, body: bytes,
                                                         reason: str) -> None:
    answer = daemon.post("/api/stage/move", content=body, headers={**daemon.auth(), "Content-Type": "application/json"})
    assert answer.status_code == 422 and reason in answer.json()["error"], answer.text  # was 400, undocumented
    assert "422" in document["paths"]["/api/stage/move"]["post"]["responses"]


@pytest.mark.parametrize("method, path, allowed", [("TRACE", "/api/status", "GET, HEAD"),
                                                   ("PUT", "/api/stage/move", "POST"),
                                                   ("DELETE", "/metrics", "GET, HEAD")])
def test_a_405_names_the_methods_allowed(daemon: LiveServer, method: str, path: str, allowed: str) -> None:
    import httpx

    answer = httpx.request(method, daemon.base + path, headers=daemon.auth(), timeout=5)
    assert answer.status_code == 405 and answer.headers["allow"] == allowed  # was absent
    assert answer.json()["error"]


def test_the_schema_refuses_what_the_server_refuses_and_takes_what_it_takes(daemon: LiveServer, document) -> None:
    """The five places: since='', a row beyond the frame, a jog of 0, a velocity of 5e-324, a target
    outside the soft limits. Each pair: the value the server refuses (422) is invalid in the schema,
    its valid neighbour is answered."""
    low, high = daemon.status()["limits_mm"]
    rows = daemon.get("/api/profile").json()["rows"]
    since, row = _parameter(document, "/api/events", "since"), _parameter(document, "/api/profile", "row")
    queries = [(since, "/api/events", {"since": ""}, 422),
               (since, "/api/events", {"since": "1970-01-01T00:00:00Z"}, 200),
               (row, "/api/profile", {"row": rows}, 422), (row, "/api/profile", {"row": rows - 1}, 200)]
    for schema, path, params, status in queries:
        value = next(iter(params.values()))
        assert _valid(document, schema, value) == (status == 200), (path, params)
        assert daemon.get(path, params=params).status_code == status, (path, params)
    bodies = [("JogRequest", "/api/stage/jog", {"step_mm": 0.0}, 422),
              ("VelocityRequest", "/api/stage/velocity", {"velocity_mm_s": 5e-324}, 422),
              ("VelocityRequest", "/api/stage/velocity", {"velocity_mm_s": 1e-9}, 200),
              ("MoveRequest", "/api/stage/move", {"target_mm": high + 0.001}, 422),
              ("MoveRequest", "/api/stage/move", {"target_mm": low - 0.001}, 422),
              ("MoveRequest", "/api/stage/move", {"target_mm": high}, 202)]
    try:
        for name, path, body, status in bodies:
            assert _valid(document, _body(document, name), body) == (status < 300), (name, body)
            assert daemon.post(path, json=body, headers=daemon.auth()).status_code == status, (path, body)
    finally:
        daemon.post("/api/stage/velocity", json={"velocity_mm_s": 20.0}, headers=daemon.auth())
    velocity = _body(document, "VelocityRequest")["properties"]["velocity_mm_s"]
    assert velocity["maximum"] == 50.0  # the simulated controller's limit, read from it at run time
    assert daemon.post("/api/stage/velocity", json={"velocity_mm_s": 50.001}, headers=daemon.auth()).status_code == 422


@pytest.mark.parametrize("since", ["1969-12-31T23:59:59Z", "0001-01-01T00:00:00Z", "9" * 19])
def test_since_outside_the_documented_range_is_422(daemon: LiveServer, document, since: str) -> None:
    answer = daemon.get("/api/events", params={"since": since})
    assert answer.status_code == 422 and "from 1970 on" in answer.json()["error"]  # 1969: was 200
    assert not _valid(document, _parameter(document, "/api/events", "since"), since)
