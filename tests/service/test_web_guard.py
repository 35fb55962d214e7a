"""Closed to the web, through a real uvicorn server: no framing, no inline script, token before
body, 64 KiB bodies, WebSocket Origin/Host checks, strict JSON numbers, a truthful OpenAPI."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from graytrack.service.daemon.app import create_app
from tests.service.helpers import LiveServer, fast_settings


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory, calibrated) -> Iterator[LiveServer]:
    folder = calibrated(tmp_path_factory.mktemp("guard"))
    with LiveServer(create_app(fast_settings(folder, allowed_origins=["https://console.lab.example"]))) as server:
        server.wait_state("tracking")
        yield server


def _raw(daemon: LiveServer, head: str, body: bytes = b"") -> tuple[int, float]:
    """Send a raw request (headers, optionally part of a body); the status and how long it took."""
    started = time.monotonic()
    with socket.create_connection(("127.0.0.1", daemon.port), timeout=5) as s:
        s.sendall(head.encode() + body)
        reply = s.recv(4096).decode(errors="replace")
    return int(reply.split()[1]), time.monotonic() - started


def test_every_page_refuses_framing_and_inline_script(daemon: LiveServer) -> None:
    for path in ("/", "/api/status", "/static/app.js", "/healthz", "/no-such-page"):
        headers = daemon.get(path).headers
        assert headers["x-frame-options"] == "DENY", path
        csp = headers["content-security-policy"]
        assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp and "unsafe-inline" not in csp, path
    assert "<script>" not in daemon.get("/").text, "no inline script on the page"


def test_the_token_is_checked_before_the_body_is_read(daemon: LiveServer) -> None:
    # 200 MB announced, nothing sent: the answer comes at once, the body is never waited for
    status, took = _raw(daemon, "POST /api/stage/move HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                                "Content-Type: application/json\r\nContent-Length: 200000000\r\n\r\n")
    assert status == 401 and took < 2.0
    token = daemon.app.state.policy.token
    status, _ = _raw(daemon, f"POST /api/stage/move HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {token}\r\n"
                             "Content-Type: application/json\r\nContent-Length: 200000000\r\n\r\n")
    assert status == 413, "over 64 KiB: refused before reading, token or not"


def test_bodies_over_64_kib_are_refused_even_when_chunked(daemon: LiveServer) -> None:
    token = daemon.app.state.policy.token
    chunk = b"[" * 40_000
    chunked = b"".join(b"%x\r\n%s\r\n" % (len(chunk), chunk) for _ in range(3)) + b"0\r\n\r\n"
    status, _ = _raw(daemon, f"POST /api/stage/move HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {token}\r\n"
                             "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n", chunked)
    assert status == 413
    small = daemon.post("/api/stage/move", json={"target_mm": 1.0, "pad": "x" * 1000}, headers=daemon.auth())
    assert small.status_code == 422 and "pad" in small.json()["error"], "a small body still reaches validation"


@pytest.mark.parametrize("body", [{"target_mm": True}, {"target_mm": "5"}, {"target_mm": None}, {"target_mm": [1]}])
def test_target_mm_is_strictly_a_json_number(daemon: LiveServer, body: dict) -> None:
    response = daemon.post("/api/stage/move", json=body, headers=daemon.auth())
    assert response.status_code == 422, response.text
    assert response.json()["error"].startswith("invalid request: target_mm"), response.text


def test_an_integer_target_is_a_number(daemon: LiveServer) -> None:
    assert daemon.post("/api/stage/move", json={"target_mm": 3}, headers=daemon.auth()).json()["target_mm"] == 3.0


def _ws(daemon: LiveServer, host: str | None = None, **headers: str) -> dict:
    """A message from the stream; ``host``: the name the handshake gives as its one Host (the socket still
    reaches the daemon on loopback, as a DNS-rebound name would)."""
    url = f"ws://{host or f'127.0.0.1:{daemon.port}'}/ws/position"
    sock = socket.create_connection(("127.0.0.1", daemon.port), timeout=5)
    with connect(url, sock=sock, additional_headers=headers, open_timeout=5) as ws:
        import json

        return json.loads(ws.recv(timeout=5))


def test_the_websocket_accepts_its_own_origin_and_configured_ones_only(daemon: LiveServer) -> None:
    assert "seq" in _ws(daemon)  # not a browser: no Origin
    assert "seq" in _ws(daemon, Origin=f"http://127.0.0.1:{daemon.port}")
    assert "seq" in _ws(daemon, Origin="https://console.lab.example")
    for origin in ("http://evil.example", f"http://127.0.0.1:{daemon.port + 1}", "null"):
        with pytest.raises(InvalidStatus) as refused:
            _ws(daemon, Origin=origin)
        assert refused.value.response.status_code == 403, origin


def test_the_websocket_refuses_a_foreign_host_name(daemon: LiveServer) -> None:
    # DNS rebinding: a foreign name resolving to 127.0.0.1, the page's own origin under that name
    with pytest.raises(InvalidStatus) as refused:
        _ws(daemon, host=f"rebind.evil.example:{daemon.port}", Origin=f"http://rebind.evil.example:{daemon.port}")
    assert refused.value.response.status_code == 403
    assert "seq" in _ws(daemon, host=f"localhost:{daemon.port}")


def test_openapi_declares_the_bearer_scheme_every_answer_and_every_schema(daemon: LiveServer) -> None:
    document = daemon.get("/api/openapi.json").json()
    assert document["components"]["securitySchemes"]["HTTPBearer"] == {
        "type": "http", "scheme": "bearer", "description": "the token from the config or DATA/token"}
    move = document["paths"]["/api/stage/move"]["post"]
    assert move["security"] == [{"HTTPBearer": []}]
    assert {"202", "401", "409", "413", "422", "503"} <= set(move["responses"])
    assert set(document["paths"]["/api/calibration/{calibration_id}"]["get"]["responses"]) >= {"200", "404"}
    assert "503" in document["paths"]["/healthz"]["get"]["responses"]
    schemas = document["components"]["schemas"]
    assert {"Status", "Calibration", "ErrorBody", "Moved", "Stopped", "Health"} <= set(schemas)
    assert daemon.get("/api/docs").status_code == 404, "the docs page loads a CDN: off unless configured"


def test_beyond_loopback_the_stream_needs_the_token(tmp_path) -> None:
    from graytrack.service.daemon.api.security import WebPolicy

    settings = fast_settings(tmp_path, host="0.0.0.0")
    policy = WebPolicy(settings.daemon, "t" * 32)
    scope = {"headers": [(b"host", b"192.0.2.7:8000")], "query_string": b""}
    assert "needs the token" in policy.websocket_refusal(scope)
    assert policy.websocket_refusal({**scope, "query_string": b"token=" + b"t" * 32}) is None
    assert policy.websocket_refusal({**scope, "headers": [*scope["headers"],
                                                          (b"authorization", b"Bearer " + b"t" * 32)]}) is None


@pytest.mark.parametrize("path", ["/api/status", "/api/events", "/", "/api/calibrations", "/healthz"])
def test_plain_http_refuses_a_rebound_host_name(daemon: LiveServer, path: str) -> None:
    """DNS rebinding: a page on evil.example resolves its own name to 127.0.0.1 and reads the
    daemon as same-origin. Every route checks Host, not only the WebSocket."""
    answer = daemon.get(path, headers={"Host": f"rebind.evil.example:{daemon.port}"})
    assert answer.status_code == 400 and "allowed_hosts" in answer.json()["error"]
    assert answer.headers["x-frame-options"] == "DENY"
    assert daemon.get(path, headers={"Host": f"localhost:{daemon.port}"}).status_code in (200, 503)


@pytest.mark.parametrize("query", ["/api/events?since=%C2%B2", "/api/events?since=18446744073709551616",
                                   "/api/events?since=0001-01-01", "/api/events?since=9999-99-99",
                                   "/api/calibrations?offset=9223372036854775808",
                                   "/api/calibrations?limit=-1", "/api/events?limit=abc"])
def test_malformed_queries_are_422_with_a_json_reason(daemon: LiveServer, query: str) -> None:
    answer = daemon.get(query)
    assert answer.status_code == 422, answer.text
    assert answer.json().get("error") and answer.headers["x-frame-options"] == "DENY"


def test_an_unforeseen_error_is_json_with_the_security_headers(tmp_path, monkeypatch) -> None:
    from graytrack.service.daemon.rig import Rig

    def broken(self):
        raise RuntimeError("a bug in a route")

    with LiveServer(create_app(fast_settings(tmp_path))) as server:
        monkeypatch.setattr(Rig, "status", broken)
        answer = server.get("/api/status")
        assert answer.status_code == 500 and "log" in answer.json()["error"]
        assert answer.headers["x-frame-options"] == "DENY"
        assert "frame-ancestors" in answer.headers["content-security-policy"]
        monkeypatch.undo()
        assert server.get("/api/status").status_code == 200, "the daemon goes on"


FLOOR = "velocity_mm_s: Input should be greater than or equal to 0.000000001"  # the schema's minimum, 1e-9


@pytest.mark.parametrize("velocity, limit", [(75.0, "(0, 50] mm/s (the controller's limit)"), (1e-12, FLOOR)])
def test_a_velocity_the_controller_cannot_take_is_422_naming_the_limit(daemon: LiveServer, velocity, limit) -> None:
    answer = daemon.post("/api/stage/velocity", json={"velocity_mm_s": velocity}, headers=daemon.auth())
    assert answer.status_code == 422 and limit in answer.json()["error"], answer.text


def test_a_json_body_without_its_content_type_is_told_which_header_is_missing(daemon: LiveServer) -> None:
    """What `curl -d '{"target_mm": 5}'` sends without -H: a form-encoded body."""
    reply = daemon.post("/api/stage/move", content=b'{"target_mm": 5.0}', headers={
        **daemon.auth(), "Content-Type": "application/x-www-form-urlencoded"})
    assert reply.status_code == 422
    assert "Content-Type: application/json" in reply.json()["error"], reply.json()
    assert "x-www-form-urlencoded" in reply.json()["error"]


def _exchange(daemon: LiveServer, raw: bytes) -> tuple[int, dict[str, str], bytes]:
    """One raw request on a fresh connection: the answer's status, headers (names lowercased) and body."""
    with socket.create_connection(("127.0.0.1", daemon.port), timeout=5) as s:
        s.sendall(raw)
        reply = b""
        while b"\r\n\r\n" not in reply and (chunk := s.recv(65536)):
            reply += chunk
        head, _, body = reply.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        headers = {name.lower(): value.strip() for name, _, value in (line.partition(":") for line in lines[1:])}
        # (an answer to HEAD has no body, whatever length it states: read on, a kept-alive connection would only
        # time out)
        expected = 0 if raw.startswith(b"HEAD ") else int(headers.get("content-length", 0))
        while len(body) < expected and (chunk := s.recv(65536)):
            body += chunk
    return int(lines[0].split()[1]), headers, body


def _secured_json_error(headers: dict[str, str], body: bytes) -> str:
    import json

    assert headers["content-type"] == "application/json", headers
    assert headers["x-frame-options"] == "DENY" and headers["x-content-type-options"] == "nosniff", headers
    assert "frame-ancestors 'none'" in headers["content-security-policy"], headers
    return json.loads(body)["error"]


@pytest.mark.parametrize("raw", [b"GARBAGE\r\n\r\n", b"GET /api/status HTTP/1.1\r\nHo st: x\r\n\r\n",
                                 b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: -4\r\n\r\n"])
def test_malformed_http_gets_a_json_400_with_the_security_headers(daemon: LiveServer, raw: bytes) -> None:
    """uvicorn answers what its parser refuses with a text/plain 400 without them (issue #48)."""
    status, headers, body = _exchange(daemon, raw)
    assert status == 400 and "not valid HTTP/1.1" in _secured_json_error(headers, body)
    assert daemon.get("/api/status").status_code == 200, "the daemon goes on"


def test_answers_the_protocol_writes_itself_carry_the_security_headers(daemon: LiveServer) -> None:
    status, headers, body = _exchange(daemon, b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: "
                                      + b"a" * 20_000 + b"\r\n\r\n")
    assert status == 431 and "16384 bytes" in _secured_json_error(headers, body)


@pytest.mark.parametrize("path", ["/", "/healthz", "/api/status", "/metrics", "/api/calibrations", "/api/events",
                                  "/static/app.js", "/favicon.ico", "/api/openapi.json"])
def test_every_get_route_answers_head_with_the_get_status_and_headers_and_no_body(daemon: LiveServer,
                                                                                   path: str) -> None:
    """HEAD was 405 on /healthz and / (issue #48); a HEAD answer is the GET's without its body."""
    got = daemon.get(path)
    status, headers, body = _exchange(daemon, f"HEAD {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                                              "Connection: close\r\n\r\n".encode())
    assert status == got.status_code and body == b"", (path, status)
    assert headers["content-type"] == got.headers["content-type"] and headers["x-frame-options"] == "DENY"
    if path != "/api/status" and path != "/metrics" and path != "/healthz":  # those change between two answers
        assert headers["content-length"] == got.headers["content-length"], path


def test_head_on_a_route_without_get_is_405_with_allow(daemon: LiveServer) -> None:
    status, headers, body = _exchange(daemon, b"HEAD /api/stage/stop HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    assert status == 405 and headers["allow"] == "POST" and body == b""


@pytest.mark.parametrize("hosts", [("evil.example", "127.0.0.1"), ("127.0.0.1", "evil.example"),
                                   ("127.0.0.1", "localhost"), ()])
def test_a_request_names_exactly_one_host(daemon: LiveServer, hosts: tuple[str, ...]) -> None:
    """Two Host headers, a foreign one first, were taken (the last one was checked; issue #48): a proxy in
    front and the daemon could each see another name. Two, or none, is 400 (RFC 9112 §3.2)."""
    lines = "".join(f"Host: {host}\r\n" for host in hosts)
    status, headers, body = _exchange(daemon, f"GET /api/status HTTP/1.1\r\n{lines}\r\n".encode())
    assert status == 400 and f"exactly once (this one: {len(hosts)} Host headers)" in _secured_json_error(headers,
                                                                                                         body)


def test_a_refused_websocket_gets_a_json_403_with_the_security_headers(daemon: LiveServer) -> None:
    """Two Host headers on the handshake, or a foreign Origin: 403 with the reason as JSON (was an empty
    text/plain 403) and the headers every answer carries."""
    import json

    for headers in ({"Host": "localhost"}, {"Origin": "http://evil.example"}):  # a Host added to the client's own
        with pytest.raises(InvalidStatus) as refused:
            _ws(daemon, **headers)
        answer = refused.value.response
        assert answer.status_code == 403 and answer.headers["content-type"] == "application/json"
        assert answer.headers["x-frame-options"] == "DENY", answer.headers
        reason = json.loads(answer.body)["error"]
        assert ("exactly once" in reason) if "Host" in headers else ("Origin" in reason), reason


@pytest.mark.parametrize("target, expected", [("http://evil.example/api/status", 400),
                                              ("http://evil.example:80/api/status", 400),
                                              ("http://127.0.0.1/api/status", 200),
                                              ("http://localhost:1/api/status", 200)])
def test_an_absolute_form_target_must_name_this_daemon(daemon: LiveServer, target: str, expected: int) -> None:
    """``GET http://evil.example/api/status`` with an own Host was served (issue #48); the target's host is
    what names the server then (RFC 9112 §3.2.2), so it is checked like Host."""
    status, headers, body = _exchange(daemon, f"GET {target} HTTP/1.1\r\nHost: 127.0.0.1:{daemon.port}\r\n"
                                              "Connection: close\r\n\r\n".encode())
    assert status == expected, body[:200]
    if expected == 400:
        assert "evil.example" in _secured_json_error(headers, body) and "allowed_hosts" in body.decode()
