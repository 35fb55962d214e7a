"""A newcomer's first minutes on the status page (issue 39, item 8), in real headless Chromium against a
running daemon at 390 px: what the page says before it has heard from the daemon, where the token is,
controls that cannot work yet, frames lost with the events that explain them, the history's badge."""

from __future__ import annotations

import re
import threading
from pathlib import Path

import pytest

from tests.service.helpers import GatedFactory, LiveServer, fast_settings, wait_for
from tests.web.conftest import CHROMIUM
from tests.web.test_status_page import watch_console

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed (apt-get install chromium)")
CONTROLS = ("#calibrate", "#move", "#jog-plus", "#home", "#set-velocity", "#stop")
NARROW = {"width": 390, "height": 844}
# [daemon] frames_lost_quiet_s (10 s): long enough that a loss the page shows stays one event while the test reads it
LOSS_QUIET_S = 2.0


def test_a_newcomer_is_told_what_the_page_waits_for_where_the_token_is_and_what_the_lost_frames_are(
        tmp_path: Path, browser, calibrated) -> None:
    from playwright.sync_api import expect

    from graytrack.service.daemon.app import create_app

    factory = GatedFactory()
    # its first calibration done (the run's, copied: tests/conftest.py calibrated): the page is the test; frames
    # lost at its start (a loaded host) hold the loss's event back for the quiet period: a short one here
    settings = fast_settings(calibrated(tmp_path / "data"), frames_lost_quiet_s=LOSS_QUIET_S)
    with LiveServer(create_app(settings, factory)) as daemon:
        daemon.wait_state("tracking", 60.0)
        page = browser.new_page(viewport=NARROW)
        console = watch_console(page)
        held: list = []
        # the status is slow to come (a loaded daemon): held back
        page.route("**/api/status", lambda route: held.append(route))
        page.goto(daemon.base + "/")
        # the stream runs meanwhile; until a status arrives the page claims nothing about the daemon
        expect(page.locator("#position")).to_have_text(re.compile(r"^\d+\.\d{4}$"), timeout=10_000)
        expect(page.locator("#state")).to_have_text("connecting…")
        assert "no model" not in page.locator("#model").text_content()
        expect(page.locator("#controls-reason")).to_have_text("waiting for the daemon's first status")
        for control in CONTROLS:
            expect(page.locator(control)).to_be_disabled()
        for route in held:  # then it comes
            route.continue_()
        page.unroute("**/api/status")  # (any held since are let through by the unroute)
        expect(page.locator("#state")).to_have_text("tracking", timeout=10_000)

        # the Access card comes before the controls that need it and names the token file by its path
        token_file = (tmp_path / "data" / "token").absolute()
        expect(page.locator("#token-where")).to_contain_text(f"the contents of {token_file} (on the daemon's "
                                                             f"machine: cat {token_file}).")
        assert page.locator("#token").get_attribute("placeholder") == f"contents of {token_file}"
        before = "([a, b]) => Boolean(document.getElementById(a).compareDocumentPosition(document.getElementById(b)) " \
                 "& Node.DOCUMENT_POSITION_FOLLOWING)"
        assert all(page.evaluate(before, ["access-card", target]) for target in ("calibrate", "move", "history"))
        # without a token every control is disabled and says why; saved, they work
        for control in CONTROLS:
            expect(page.locator(control)).to_be_disabled()
            assert page.locator(control).get_attribute("title") == "save the bearer token under Access first"
        expect(page.locator("#controls-reason")).to_have_text("save the bearer token under Access first")
        expect(page.locator("#token-state")).to_contain_text("No token saved in this browser yet")
        page.fill("#token", token_file.read_text().strip())
        page.click("#save-token")
        for control in CONTROLS:
            expect(page.locator(control)).to_be_enabled(timeout=5_000)
        expect(page.locator("#controls-reason")).to_have_text("")

        # frames lost: named, no "?", the share and where each loss is told
        figures = page.locator(".figures")
        assert "?" not in figures.text_content() and "frames lost" in figures.locator("dt").all_text_contents()
        lost_before = daemon.status()["dropped"]  # the first calibration's fit may have lost some (95 seen)
        logged = page.locator("#events li[data-kind=frames_lost]")

        def losses_logged() -> int:  # events, not lines: frames_lost events in a row are one line with a count
            return sum(int(n) for n in logged.evaluate_all("items => items.map(li => li.dataset.count)"))

        logged_before = losses_logged()
        factory.hardware.camera.lose = 7  # the link loses seven frames
        expect(page.locator("#dropped")).not_to_have_text(str(lost_before), timeout=10_000)
        note = page.locator("#dropped-note")
        expect(note).to_contain_text(re.compile(r"^frames lost: (\d+) of the \d+ camera frames since the daemon "
                                                r"started never reached the tracker \(\d+\.\d %; gaps in the "
                                                r"camera's frame counter"), timeout=10_000)
        # logged within the events' quiet period; a loaded host may lose more frames of its own meanwhile, and
        # the page may fetch two events in one poll: the newest event's total is what must cover the seven
        def logged_total() -> int:
            if losses_logged() <= logged_before:
                return 0
            newest = logged.first.locator(".text").text_content()
            told = re.search(r"camera frames? lost .*: (\d+) since start$", newest)
            return int(told.group(1)) if told else 0

        told = wait_for(lambda: logged_total() >= lost_before + 7 and logged_total(), 15.0,
                        "the loss in the event log", show=lambda: (losses_logged(), logged_before, lost_before))
        shown = int(page.locator("#dropped").text_content())
        assert shown >= lost_before + 7 and told >= lost_before + 7, (shown, told, lost_before)

        # History at 390 px: the active calibration's badge reads on one line
        expect(page.locator("#history tbody tr")).to_have_count(1, timeout=10_000)
        badge = page.locator("#history button.activate").first
        expect(badge).to_have_text("active")
        height, font = badge.evaluate("b => [b.getBoundingClientRect().height, "
                                      "parseFloat(getComputedStyle(b).fontSize)]")
        assert height < 2.5 * font, (height, font)  # one line with its padding (wrapped: 53 px at 14.4 px type)
        assert page.evaluate("document.documentElement.scrollWidth") <= 390
        assert console == [], console


def test_while_the_daemon_warms_up_the_page_says_what_it_is_doing(tmp_path: Path, browser,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from playwright.sync_api import expect

    from graytrack.service.daemon import app as app_module

    compiled = threading.Event()  # numba compiling the tracker's kernels on a first start (~30 s)
    monkeypatch.setattr(app_module, "warm_tracking", lambda engines=(): compiled.wait(30.0))
    try:
        with LiveServer(app_module.create_app(fast_settings(tmp_path / "data", auto_calibrate="never"))) as daemon:
            page = browser.new_page(viewport=NARROW)
            console = watch_console(page)
            page.goto(daemon.base + "/")
            expect(page.locator("#state")).to_have_text("starting", timeout=10_000)
            expect(page.locator("#reason")).to_contain_text(re.compile(
                r"^loading the tracker's compiled kernels: \d+ s \(under a second from numba's cache; about 30 s"))
            expect(page.locator("#controls-reason")).to_have_text("disabled while the daemon warms up")
            compiled.set()
            expect(page.locator("#state")).to_have_text("idle", timeout=20_000)
            expect(page.locator("#reason")).to_have_text("")
            expect(page.locator("#model")).to_have_text("no model: start a calibration")
            assert console == [], console
    finally:
        compiled.set()
