"""The status page in real headless Chromium against a running daemon (``graytrack serve``)."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.service.helpers import ServeProcess, wait_for

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed (apt-get install chromium)")


@pytest.fixture
def page(tmp_path: Path) -> Iterator[tuple[object, ServeProcess]]:
    sync_api = pytest.importorskip("playwright.sync_api")
    with ServeProcess(tmp_path) as daemon, sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True)
        try:
            yield browser.new_page(), daemon
        finally:
            browser.close()


def test_page_shows_live_position_and_runs_a_calibration(page) -> None:
    from playwright.sync_api import expect

    browser_page, daemon = page
    daemon.wait_state("tracking")
    browser_page.goto(daemon.base + "/")
    expect(browser_page.locator("#state")).to_have_text("tracking", timeout=10_000)
    position = browser_page.locator("#position")
    expect(position).to_have_text(re.compile(r"^\d+\.\d{4}$"), timeout=10_000)
    first = position.text_content()
    expect(position).not_to_have_text(first, timeout=10_000)

    # without a token the daemon refuses, and the page says why
    browser_page.click("#calibrate")
    expect(browser_page.locator("#message")).to_contain_text("missing bearer token")

    token = (daemon.folder / "data" / "token").read_text().strip()
    browser_page.fill("#token", token)
    browser_page.click("#save-token")
    assert browser_page.evaluate("localStorage.getItem('graytrack.token')") == token
    browser_page.click("#calibrate")
    expect(browser_page.locator("#message")).to_contain_text(re.compile(r"calibration \d{8}T\d+Z started"))
    job_id = browser_page.locator("#message").text_content().split()[1]
    calibration = browser_page.locator("#calibration-message")
    expect(calibration).to_contain_text(job_id, timeout=10_000)
    wait_for(lambda: browser_page.evaluate("document.getElementById('progress').value") > 0, what="progress")
    expect(calibration).to_contain_text("done", timeout=20_000)
    expect(browser_page.locator("#state")).to_have_text("tracking", timeout=10_000)

    # a move from the form is tracked to its target
    browser_page.fill("#target", "3.5")
    browser_page.click("#move")
    expect(browser_page.locator("#message")).to_have_text("moving to 3.5 mm")
    expect(position).to_have_text(re.compile(r"^3\.(49[89]|50[012])\d$"), timeout=10_000)


def test_a_page_on_another_origin_cannot_frame_the_status_page(page, tmp_path: Path) -> None:
    import functools
    import http.server
    import threading

    browser_page, daemon = page
    daemon.wait_state("tracking")
    site = tmp_path / "site"
    site.mkdir()
    (site / "own.html").write_text('<p id="own">the attacker\'s own page</p>')
    (site / "index.html").write_text(f'<iframe id="victim" src="{daemon.base}/"></iframe>'
                                     '<iframe id="control" src="/own.html"></iframe>')
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(site))
    attacker = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=attacker.serve_forever, daemon=True).start()
    try:
        browser_page.goto(f"http://127.0.0.1:{attacker.server_address[1]}/index.html")
        browser_page.wait_for_timeout(1500)
        frames = {frame.url: frame for frame in browser_page.frames[1:]}
        control = next(f for url, f in frames.items() if url.endswith("/own.html"))
        assert control.query_selector("#own") is not None, "the control frame loads: framing as such works"
        victim = [f for url, f in frames.items() if not url.endswith("/own.html")]
        assert victim and all(f.query_selector("#position") is None for f in victim), [f.url for f in victim]
    finally:
        attacker.shutdown()
