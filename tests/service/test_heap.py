"""The daemon moves its long-lived heap out of the collector's full passes while it runs, and back
when it stops (a daemon inside a longer-lived process, as in these tests, frees what it built)."""

from __future__ import annotations

import gc

from fastapi.testclient import TestClient

from graytrack.service.daemon.app import create_app
from tests.service.helpers import fast_settings


def test_the_running_daemon_keeps_its_start_up_heap_frozen_and_thaws_it_at_shutdown(tmp_path) -> None:
    gc.unfreeze()
    with TestClient(create_app(fast_settings(tmp_path, auto_calibrate="never"))) as client:
        assert client.get("/healthz").status_code in (200, 503)
        assert gc.get_freeze_count() > 10_000  # the modules, the app, the drivers
    assert gc.get_freeze_count() == 0
