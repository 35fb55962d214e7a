"""The daemon's warm-up runs off the event loop (service/daemon/startup.py): on a first start, whose
kernels compile for ~30 s, the API answers meanwhile with what the daemon is doing, and the log says it."""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import pytest

from tests.service.helpers import LiveServer, fast_settings, wait_for


def test_the_status_route_answers_during_a_slow_warm_up_with_its_step_then_the_rig_opens(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    from graytrack.service.daemon import app as app_module
    from graytrack.service.heap import warm_tracking

    compiled = threading.Event()  # stands for numba compiling the kernels (tens of seconds with no cache)

    def first_start_warm_up(engines: tuple[str, ...] = ("watches",)) -> None:
        compiled.wait(30.0)
        warm_tracking(engines)

    monkeypatch.setattr(app_module, "warm_tracking", first_start_warm_up)
    caplog.set_level(logging.INFO, logger="graytrack.daemon")
    with LiveServer(app_module.create_app(fast_settings(tmp_path, auto_calibrate="never"))) as daemon:
        first = daemon.status()  # answered at once, not after the warm-up
        assert first["state"] == "starting" and first["startup"]["step"] == "loading the tracker's compiled kernels"
        assert "about 30 s on the first start after an install" in first["startup"]["expected_s"]
        later = wait_for(lambda: (s := daemon.status())["startup"]["elapsed_s"] >= 0.3 and s, 10.0, "time to pass")
        assert later["state"] == "starting" and daemon.rig.acquisition is None  # the rig waits for the warm-up
        assert daemon.get("/healthz").status_code == 503
        assert any("the API answers meanwhile" in r.getMessage() for r in caplog.records)
        compiled.set()
        opened = daemon.wait_state("idle", 20.0)  # no saved model, auto_calibrate never
        assert opened["startup"] is None
        assert any(r.getMessage().startswith("tracker kernels ready in ") for r in caplog.records)


def test_a_shutdown_during_the_warm_up_never_opens_the_rig(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from graytrack.service.daemon import app as app_module

    release = threading.Event()
    monkeypatch.setattr(app_module, "warm_tracking", lambda engines=(): release.wait(30.0))
    app = app_module.create_app(fast_settings(tmp_path, auto_calibrate="never"))
    with LiveServer(app) as daemon:
        assert daemon.status()["state"] == "starting"
    release.set()
    wait_for(lambda: app.state.startup.seconds is not None, 5.0, "the warm-up thread to end")
    assert app.state.rig.acquisition is None and not app.state.rig.supervisor.thread.is_alive()
