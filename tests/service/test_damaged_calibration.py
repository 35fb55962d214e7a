"""A calibration whose ``model.json`` is damaged: activating it is 409 naming the file and the cause (not a
500 with the reason only in the log), and the list says it is damaged; nothing changes on the daemon."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from graytrack.service.daemon.app import create_app
from tests.service.helpers import fast_settings, wait_state

DAMAGE = {
    # what the file holds instead of a model, and the words the answer must name the cause with
    "another schema": (lambda text: json.dumps({"schema": "someone.else", "version": 1}), "not a graytrack model file"),
    "not JSON": (lambda text: text[: len(text) // 2], "not a JSON model file"),
    "missing": (None, "no such model file"),
    "a key missing": (lambda text: json.dumps({k: v for k, v in json.loads(text).items() if k != "model"}),
                      "has no 'model' object"),
}


@pytest.mark.parametrize("kind", list(DAMAGE))
def test_activating_a_damaged_calibration_is_409_naming_the_file_and_the_list_says_so(
        tmp_path: Path, two_calibrations: list[str], kind: str) -> None:
    older, newer = two_calibrations
    model_file = tmp_path / "data" / "calibrations" / older / "model.json"
    rewrite, cause = DAMAGE[kind]
    if rewrite is None:
        model_file.unlink()
    else:
        model_file.write_text(rewrite(model_file.read_text()))
    active_before = (tmp_path / "data" / "active").read_text()
    in_use_before = (tmp_path / "data" / "model.json").read_bytes()
    app = create_app(fast_settings(tmp_path / "data", auto_calibrate="never"))
    with TestClient(app) as client:
        wait_state(client, "tracking", 20.0)
        headers = {"Authorization": f"Bearer {app.state.policy.token}"}
        answer = client.post(f"/api/calibrations/{older}/activate", headers=headers)
        assert answer.status_code == 409, answer.text
        error = answer.json()["error"]
        assert str(model_file) in error and cause in error and older in error, error

        rows = {row["id"]: row for row in client.get("/api/calibrations").json()["items"]}
        assert rows[older]["damaged"] is not None and cause in rows[older]["damaged"], rows[older]
        assert rows[newer]["damaged"] is None and rows[newer]["active"]
        assert client.get(f"/api/calibrations/{older}").json()["damaged"] == rows[older]["damaged"]
        status = client.get("/api/status").json()
        assert status["active_calibration"]["id"] == newer, "the model in use is still the newer one"
    assert (tmp_path / "data" / "active").read_text() == active_before
    assert (tmp_path / "data" / "model.json").read_bytes() == in_use_before


def test_a_repaired_model_file_is_listed_whole_again(tmp_path: Path, two_calibrations: list[str]) -> None:
    """The list's check is remembered per file version, not forever: putting the file back clears it."""
    older, _ = two_calibrations
    model_file = tmp_path / "data" / "calibrations" / older / "model.json"
    whole = model_file.read_text()
    model_file.write_text("{")
    app = create_app(fast_settings(tmp_path / "data", auto_calibrate="never"))
    with TestClient(app) as client:
        wait_state(client, "tracking", 20.0)
        assert client.get(f"/api/calibrations/{older}").json()["damaged"]
        model_file.write_text(whole)
        assert client.get(f"/api/calibrations/{older}").json()["damaged"] is None
        headers = {"Authorization": f"Bearer {app.state.policy.token}"}
        assert client.post(f"/api/calibrations/{older}/activate", headers=headers).status_code == 200
