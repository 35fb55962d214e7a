"""The daemon's saved model against a camera whose readout changed since its calibration (a pixel format set from 8
to 12 bits): the model is refused at startup with the cause and the fix, an event says so, and activating it again is
a conflict with the camera's configuration (409), not a wait."""

from __future__ import annotations

from fastapi.testclient import TestClient

from graytrack.service.daemon.app import create_app
from tests.service.helpers import activate_refused, fast_settings, wait_state


def test_a_camera_read_out_on_another_range_than_the_saved_models_is_refused(tmp_path) -> None:
    eight = fast_settings(tmp_path / "data", {"camera": {"effects": "quantize:bits=8"}})
    with TestClient(create_app(eight)) as client:
        wait_state(client, "tracking", 60.0)
        assert client.app.state.rig.model.info["sensor_range_gray"] == [0.0, 255.0]

    twelve = fast_settings(tmp_path / "data", {"camera": {"effects": "quantize:bits=12"}})
    with TestClient(create_app(twelve)) as client:
        status = wait_state(client, "fault", 20.0)
        assert status["calibrated"] is False
        refusal = activate_refused(client, "pixels", "0-255", "0-4095")
        assert "set the camera's pixel format back" in refusal["error"]

    # back at 8 bits the same saved model tracks again
    with TestClient(create_app(eight)) as client:
        wait_state(client, "tracking", 20.0)
