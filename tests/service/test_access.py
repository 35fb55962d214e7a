"""``GET /api/access``: the page names the token file by its real path (service/daemon/api/access.py)."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from graytrack.service.daemon.app import create_app
from graytrack.wire import Access
from tests.service.helpers import fast_settings


def test_the_token_file_is_named_by_its_absolute_path_and_holds_the_token_that_authorises(tmp_path: Path) -> None:
    with TestClient(create_app(fast_settings(tmp_path / "data", auto_calibrate="never"))) as client:
        access = Access.model_validate(client.get("/api/access").json())
        assert (access.token_from, access.data_dir) == ("file", str((tmp_path / "data").absolute()))
        assert access.token_file == str((tmp_path / "data" / "token").absolute())
        token = Path(access.token_file).read_text().strip()
        assert token and token not in client.get("/api/access").text  # the path, never the token
        refused = client.post("/api/trim/reset")
        assert refused.status_code == 401
        assert client.post("/api/trim/reset", headers={"Authorization": f"Bearer {token}"}).status_code != 401


def test_a_token_from_the_configuration_has_no_file_to_name(tmp_path: Path) -> None:
    settings = fast_settings(tmp_path / "data", auto_calibrate="never", token="a-configured-token-of-32-chars-xx")
    with TestClient(create_app(settings)) as client:
        body = client.get("/api/access").json()
        assert (body["token_from"], body["token_file"]) == ("config", None)
        assert "a-configured-token" not in client.get("/api/access").text
