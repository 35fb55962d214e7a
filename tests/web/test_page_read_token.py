"""The page on a daemon whose reads need the token (``[daemon] read_token = "always"``), in real headless
Chromium: before a token is saved it shows no data (every read is refused); once saved, its reads carry the
token in a header and its stream in the WebSocket subprotocol (never in a URL), and it shows the live rig."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.service.helpers import ServeProcess
from tests.web.conftest import CHROMIUM
from tests.web.test_status_page import watch_console

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed (apt-get install chromium)")


def test_the_page_reads_and_streams_with_the_saved_token_under_the_read_policy(tmp_path: Path, browser,
                                                                               calibrated) -> None:
    from playwright.sync_api import expect

    calibrated(tmp_path / "data")  # tracking from its start: the page is the test, not the first calibration
    stdout = tmp_path / "stdout.log"
    with ServeProcess(tmp_path, stdout_path=stdout, daemon={"read_token": "always", "log_level": "debug"}) as daemon:
        daemon.wait_state("tracking")
        page = browser.new_page()
        console = watch_console(page)
        requests: list[str] = []
        page.on("request", lambda request: requests.append(request.url))
        page.goto(daemon.base + "/")
        expect(page.locator("#state")).not_to_have_text("tracking", timeout=3_000)
        assert page.locator("#position").text_content() in ("", "—"), "nothing read without the token"

        # the page's first reads refused before the token is saved (on a loaded machine they may take a while:
        # the token is saved once they were, not at a fixed moment)
        for _ in range(100):
            if console:
                break
            page.wait_for_timeout(100)
        token = (daemon.folder / "data" / "token").read_text().strip()
        page.fill("#token", token)
        page.click("#save-token")
        refused_before = len(console)  # reads 401 and handshakes 403 until the token was saved
        expect(page.locator("#state")).to_have_text("tracking", timeout=15_000)
        expect(page.locator("#position")).to_have_text(re.compile(r"^\d+\.\d{4}$"), timeout=15_000)
        page.wait_for_timeout(1_500)  # a poll or two more with the token
        after = console[refused_before:]
        assert not any(token in url for url in requests), "the token never in a URL"
        page.close()
        assert daemon.terminate() == 0
    assert token not in daemon.stderr + stdout.read_text()
    assert refused_before > 0, "without the token the page was refused"
    # the requests in flight when the token was saved may still be refused; none after
    assert len([error for error in after if "401" in error or "403" in error]) <= 2, after
