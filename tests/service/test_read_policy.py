"""One read policy (``[daemon] read_token``) for every read route and the stream: under each policy and bind
address, every read route answers without the token exactly when the policy says reads are open, takes the
token in the header or the query (the stream: the header, the subprotocol or the query), refuses a wrong one,
and the routes a newcomer needs before having the token stay open."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from starlette.testclient import WebSocketDenialResponse

from graytrack.service.daemon.app import create_app
from tests.service.helpers import fast_settings

WRONG = "a-wrong-token-of-more-than-16-chars"
OPEN = ("/", "/favicon.ico", "/healthz", "/api/access", "/api/openapi.json", "/static/app.js")
# (policy, bind address, whether reads need the token)
POLICIES = [("beyond_loopback", "127.0.0.1", False), ("beyond_loopback", "0.0.0.0", True),
            ("always", "127.0.0.1", True), ("never", "0.0.0.0", False)]


def _reads(calibration: str) -> list[str]:
    """Every read route (and a path that names none: which routes exist is not told either)."""
    return ["/api/status", "/api/profile", "/api/maps", "/api/events", "/api/calibrations",
            f"/api/calibrations/{calibration}",
            f"/api/calibrations/{calibration}/files/model.json", f"/api/calibrations/{calibration}/files/report.json",
            f"/api/calibrations/{calibration}/files/recording.npz", "/api/calibration/latest",
            f"/api/calibration/{calibration}", "/metrics", "/api/no-such-route"]


@pytest.mark.parametrize("policy,host,needed", POLICIES)
def test_every_read_route_follows_the_one_read_policy(tmp_path: Path, two_calibrations: list[str], policy: str,
                                                      host: str, needed: bool) -> None:
    app = create_app(fast_settings(tmp_path / "data", auto_calibrate="never", host=host, read_token=policy))
    token = app.state.policy.token
    with TestClient(app) as client:
        for path in _reads(two_calibrations[0]):
            bare = client.get(path)
            if needed:
                assert bare.status_code == 401, (path, bare.status_code)
                assert "needs the token for reads" in bare.json()["error"]
                assert bare.headers["www-authenticate"] == "Bearer"
                assert bare.headers["x-frame-options"] == "DENY", "refused with the security headers"
                wrong = client.get(path, headers={"Authorization": f"Bearer {WRONG}"})
                assert wrong.status_code == 401 and wrong.json()["error"] == "invalid bearer token", path
                assert client.get(path, params={"token": WRONG}).status_code == 401, path
            else:
                assert bare.status_code != 401, (path, bare.text)
            for given in ({"headers": {"Authorization": f"Bearer {token}"}}, {"params": {"token": token}}):
                assert client.get(path, **given).status_code != 401, (path, given)  # type: ignore[arg-type]
        for path in OPEN:
            assert client.get(path).status_code != 401, path

        _stream_follows_the_policy(client, token, needed)


def _stream_follows_the_policy(client: TestClient, token: str, needed: bool) -> None:
    if needed:
        for refused in ({}, {"headers": {"Authorization": f"Bearer {WRONG}"}},
                        {"subprotocols": ["graytrack", f"graytrack.bearer.{WRONG}"]}):
            # refused at the handshake: 403 with the reason as JSON (the security headers with it)
            with pytest.raises(WebSocketDenialResponse) as denied:
                with client.websocket_connect("/ws/position", **refused):  # type: ignore[arg-type]
                    pass
            assert denied.value.status_code == 403, refused
            assert "token" in denied.value.json()["error"], refused
    else:
        with client.websocket_connect("/ws/position") as stream:
            assert stream.accepted_subprotocol is None
    with client.websocket_connect("/ws/position", subprotocols=["graytrack", f"graytrack.bearer.{token}"]) as stream:
        assert stream.accepted_subprotocol == "graytrack", "the plain protocol answered, never the one with the token"
    with client.websocket_connect("/ws/position", headers={"Authorization": f"Bearer {token}"}):
        pass
    with client.websocket_connect(f"/ws/position?token={token}"):
        pass


def test_a_state_change_takes_the_token_only_from_the_header(tmp_path: Path) -> None:
    """The query and the subprotocol are ways to read; a state change still needs the header."""
    app = create_app(fast_settings(tmp_path, auto_calibrate="never", read_token="always"))
    token = app.state.policy.token
    with TestClient(app) as client:
        answer = client.post("/api/stage/stop", params={"token": token})
        assert answer.status_code == 401 and "missing bearer token" in answer.json()["error"]
