"""The status page in real headless Chromium against a running daemon (``graytrack serve``)."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.service.helpers import GatedFactory, LiveServer, ServeProcess, fast_settings, wait_for
from tests.web.conftest import CHROMIUM

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed (apt-get install chromium)")

FAINT = 0.95  # reflectance: a decided place lighter than this is no speck of the rig's dust (0.5 deep at its centre)


def watch_console(browser_page) -> list[str]:
    """Every console error and uncaught exception of the page, collected as it runs."""
    errors: list[str] = []
    browser_page.on("console", lambda message: errors.append(message.text) if message.type == "error" else None)
    browser_page.on("pageerror", lambda error: errors.append(str(error)))
    return errors


@pytest.fixture
def page(tmp_path: Path, browser, calibrated) -> Iterator[tuple[object, ServeProcess]]:
    """A daemon tracking on its first calibration (made before, tests/conftest.py calibrated), and a page."""
    calibrated(tmp_path / "data")
    with ServeProcess(tmp_path) as daemon:
        yield browser.new_page(), daemon


def test_page_shows_live_position_and_runs_a_calibration(page) -> None:
    from playwright.sync_api import expect

    browser_page, daemon = page
    console = watch_console(browser_page)
    daemon.wait_state("tracking")
    browser_page.goto(daemon.base + "/")
    expect(browser_page.locator("#state")).to_have_text("tracking", timeout=10_000)
    expect(browser_page.locator("#sim-badge")).to_be_visible()
    position = browser_page.locator("#position")
    expect(position).to_have_text(re.compile(r"^\d+\.\d{4}$"), timeout=10_000)
    first = position.text_content()
    expect(position).not_to_have_text(first, timeout=10_000)

    # without a token the controls are disabled, and say why
    expect(browser_page.locator("#calibrate")).to_be_disabled()
    assert browser_page.locator("#calibrate").get_attribute("title") == "save the bearer token under Access first"

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

    # the new calibration is in the history with its held-out error in µm, and its report opens
    history = browser_page.locator("#history tbody tr")
    expect(history).to_have_count(2, timeout=10_000)
    newest = history.first
    assert newest.get_attribute("data-id") == job_id and "active" in newest.get_attribute("class")
    expect(newest).to_contain_text(re.compile(r"\d\.\d\d µm \(bound \d\.\d\d µm\)"))
    expect(browser_page.locator("#active-calibration")).to_contain_text(re.compile(r"held-out error \d\.\d\d µm"))
    with browser_page.context.expect_page() as opened:
        newest.locator("a.report-link").click()
    report = opened.value
    report.wait_for_load_state()
    assert "held-out error" in report.text_content("body") and job_id in report.title()
    report.close()

    # rolling back to the first calibration changes the model in use, and says so
    first = history.nth(1)
    first_id = first.get_attribute("data-id")
    browser_page.once("dialog", lambda dialog: dialog.dismiss())  # asked first; "cancel" changes nothing
    first.locator("button.activate").click()
    assert daemon.status()["active_calibration"]["id"] == job_id
    asked: list[str] = []
    browser_page.once("dialog", lambda dialog: (asked.append(dialog.message), dialog.accept()))
    first.locator("button.activate").click()
    expect(browser_page.locator("#message")).to_have_text(f"calibration {first_id} is active")
    assert asked and first_id in asked[0], asked
    assert daemon.status()["active_calibration"]["id"] == first_id
    expect(history.nth(1)).to_have_class(re.compile("active"), timeout=5_000)
    expect(browser_page.locator("#events")).to_contain_text(f"model of calibration {first_id} activated")

    # a move from the form is tracked to its target; a refused value leaves no false message
    browser_page.fill("#target", "3.5")
    browser_page.click("#move")
    expect(browser_page.locator("#message")).to_have_text("moving to 3.5 mm")
    expect(position).to_have_text(re.compile(r"^3\.(49[89]|50[012])\d$"), timeout=10_000)
    browser_page.fill("#target", "25")
    browser_page.click("#move")
    expect(browser_page.locator("#message")).to_have_text("target_mm 25 is outside the soft limits [0, 10.46] mm")
    browser_page.click("#jog-plus")
    expect(browser_page.locator("#message")).to_have_text(re.compile(r"^moving to 3\.6\d* mm$"))
    assert console == [], console


def test_a_page_on_another_origin_cannot_frame_the_status_page(browser, tmp_path: Path) -> None:
    import functools
    import http.server
    import threading

    site = tmp_path / "site"
    site.mkdir()
    (site / "own.html").write_text('<p id="own">the attacker\'s own page</p>')
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(site))
    attacker = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=attacker.serve_forever, daemon=True).start()
    # A daemon that does not calibrate itself: the page (web/index.html, static) and the headers that forbid framing
    # it are served the same in every state; a start-up calibration would only take the test's CPU.
    try:
        with ServeProcess(tmp_path, daemon={"auto_calibrate": "never"}) as daemon:
            daemon.wait_state("idle")
            (site / "index.html").write_text(f'<iframe id="victim" src="{daemon.base}/"></iframe>'
                                             '<iframe id="control" src="/own.html"></iframe>')
            browser_page = browser.new_page()
            browser_page.goto(f"http://127.0.0.1:{attacker.server_address[1]}/index.html")
            browser_page.wait_for_timeout(1500)
            frames = {frame.url: frame for frame in browser_page.frames[1:]}
            control = next(f for url, f in frames.items() if url.endswith("/own.html"))
            assert control.query_selector("#own") is not None, "the control frame loads: framing as such works"
            victim = [f for url, f in frames.items() if not url.endswith("/own.html")]
            assert victim and all(f.query_selector("#position") is None for f in victim), [f.url for f in victim]
    finally:
        attacker.shutdown()


def test_the_line_view_shows_the_frame_with_the_model_following_it(tmp_path: Path, browser, calibrated) -> None:
    from playwright.sync_api import expect

    from graytrack.service.daemon.app import create_app

    with LiveServer(create_app(fast_settings(calibrated(tmp_path)))) as daemon:
        daemon.wait_state("tracking")
        browser_page = browser.new_page(viewport={"width": 390, "height": 844})
        console = watch_console(browser_page)
        browser_page.goto(daemon.base + "/")
        canvas = browser_page.locator("#profile")
        expect(canvas).to_have_attribute("data-model", "yes", timeout=10_000)
        frames = set()
        for _ in range(3):  # updated a few times a second, and the overlay fits each new frame
            frame_id = canvas.get_attribute("data-frame-id")
            frames.add(frame_id)
            residual = float(canvas.get_attribute("data-residual-rms"))
            noise = float(canvas.get_attribute("data-noise"))
            assert residual < 1.5 * noise, (residual, noise)
            expect(canvas).not_to_have_attribute("data-frame-id", frame_id, timeout=5_000)
        assert len(frames) == 3
        slow = daemon.post("/api/stage/velocity", json={"velocity_mm_s": 0.2}, headers=daemon.auth())
        assert slow.json() == {"velocity_mm_s": 0.2}  # 2 mm per wall second at the test's 10x clock
        assert daemon.post("/api/stage/move", json={"target_mm": 3.0}, headers=daemon.auth()).status_code == 202
        expect(browser_page.locator("#moving")).to_have_text("moving → 3 mm", timeout=5_000)
        wait_for(lambda: abs((daemon.status()["position_mm"] or 0) - 3.0) < 0.01, 20.0, "the move")
        assert float(canvas.get_attribute("data-residual-rms")) < 1.5 * float(canvas.get_attribute("data-noise"))
        # usable at 390 px: nothing wider than the screen, the history's actions reachable without
        # scrolling sideways, and the answer to an action in sight at the top of the page
        assert browser_page.evaluate("document.documentElement.scrollWidth") <= 390
        expect(browser_page.locator("#history tbody tr")).to_have_count(1, timeout=10_000)
        table = browser_page.locator("#history")
        assert table.evaluate("t => t.scrollWidth <= t.parentElement.clientWidth"), "the history scrolls sideways"
        button_right = table.locator("button.activate").first.evaluate("b => b.getBoundingClientRect().right")
        assert button_right <= 390, button_right
        browser_page.evaluate("window.scrollTo(0, 0)")
        browser_page.fill("#token", (tmp_path / "token").read_text().strip())
        browser_page.click("#save-token")
        expect(browser_page.locator("#message")).to_have_text("token saved in this browser")
        expect(browser_page.locator("#message")).to_be_in_viewport()
        assert console == [], console


def test_a_fault_is_in_the_event_log_and_disables_the_controls_with_its_reason(tmp_path: Path, browser,
                                                                              calibrated) -> None:
    from playwright.sync_api import expect

    from graytrack.service.daemon.app import create_app

    factory = GatedFactory()
    with LiveServer(create_app(fast_settings(calibrated(tmp_path)), factory)) as daemon:
        daemon.wait_state("tracking")
        browser_page = browser.new_page(viewport={"width": 390, "height": 844})
        console = watch_console(browser_page)
        browser_page.goto(daemon.base + "/")
        browser_page.fill("#token", daemon.app.state.policy.token)  # the controls need it
        browser_page.click("#save-token")
        expect(browser_page.locator("#move")).to_be_enabled(timeout=10_000)
        factory.hardware.camera.gate_open = False
        expect(browser_page.locator("#state")).to_have_text("fault", timeout=10_000)
        expect(browser_page.locator("#reason")).to_contain_text(re.compile(r"^camera: no frame for \d+\.\d s\.$"))
        expect(browser_page.locator("#events li[data-kind=fault]").first).to_contain_text("camera: no frame for",
                                                                                          timeout=10_000)
        for control in ("#move", "#jog-plus", "#home", "#set-velocity", "#calibrate"):
            expect(browser_page.locator(control)).to_be_disabled()
        expect(browser_page.locator("#controls-reason")).to_contain_text("disabled during the fault: camera: no frame "
                                                                         "for")
        expect(browser_page.locator("#stop")).to_be_enabled()
        assert browser_page.evaluate("document.documentElement.scrollWidth") <= 390, "the long reason wraps at 390 px"
        factory.hardware.camera.gate_open = True
        expect(browser_page.locator("#state")).to_have_text("tracking", timeout=10_000)
        # (the event list is the page's own poll, a little after the state on a loaded machine: the state's 10 s)
        expect(browser_page.locator("#events li[data-kind=recovered]").first).to_contain_text("camera recovered",
                                                                                              timeout=10_000)
        expect(browser_page.locator("#move")).to_be_enabled()
        assert console == [], console


def test_the_print_texture_learned_is_shown_where_and_how_sure(tmp_path: Path, browser, calibrated) -> None:
    """Dust settles on the print (the model was not told): the page's "Print texture" line says how many
    marks the daemon learned, where the newest is on the target and how sure, from ``/api/status``."""
    from playwright.sync_api import expect

    from graytrack.service.daemon.app import create_app
    from tests.service.test_texture_store import DUST, learn

    with LiveServer(create_app(fast_settings(calibrated(tmp_path), tables=DUST))) as daemon:
        browser_page, console = phone_page(daemon, browser)
        line = browser_page.locator("#texture")
        expect(line).to_have_attribute("data-marks", re.compile(r"^\d+$"), timeout=10_000)
        texture = learn(daemon)
        expect(line).not_to_have_attribute("data-marks", re.compile(r"^[012]$"), timeout=10_000)
        # a mark that brightens the print reads a negative depth (one learned at the turning point, −321 %)
        expect(line).to_have_text(re.compile(r"^\d+ marks learned on the print · newest at x_w = \d+\.\d{3} mm "
                                             r"\(-?\d+\.\d % ± \d+\.\d % of the light, \d+ frames\)"), timeout=10_000)
        # a mark may stop fitting and be dropped meanwhile (17 learned, 15 shown once): the page follows status
        assert int(line.get_attribute("data-marks")) >= 3 and texture["marks"] >= 3

        def same_newest() -> bool:
            """The page's newest place is status's (the newest mark is refined while the page polls: 11.642 read,
            11.649 shown, the same mark, not a copy), or status learned more since. Polled: a mark learned and
            another dropped between the page's poll and this read leave the count as it was and the page a
            poll behind (14 and 14 marks, 3.775 mm shown against 2.951 mm under load)."""
            shown = daemon.status()["texture"]
            shown_x = float(re.search(r"x_w = (\d+\.\d+) mm", line.text_content()).group(1))
            return abs(shown_x - shown["newest"][0]["x_mm"]) < 0.05 or shown["marks"] > texture["marks"]

        wait_for(same_newest, 10.0, "the page's newest mark to be status's",
                 show=lambda: (line.text_content(), daemon.status()["texture"]["newest"]))
        # the marks drawn along the target with their depth; this engine keeps no sensor map, and the page says so
        along = browser_page.locator("#texture-map")
        expect(along).not_to_have_attribute("data-marks", re.compile(r"^[012]?$"), timeout=10_000)
        # (polled, the page drawing the map at every status it reads: once, under load, its labels were read empty
        # after its count of marks had been set; what the console said then is shown with a timeout)
        wait_for(lambda: {"depth", "x_w (mm)"} <= set(canvas_labels(browser_page, "#texture-map")), 10.0,
                 "the texture's map drawn with its axes",
                 show=lambda: (along.get_attribute("data-marks"), canvas_labels(browser_page, "#texture-map"), console))
        assert "no sensor map: this engine keeps none" in canvas_labels(browser_page, "#sensor-map")
        expect(browser_page.locator("#sensor-map-info")).to_contain_text("no sensor map")
        assert browser_page.evaluate("document.documentElement.scrollWidth") <= 390
        assert console == [], console


def phone_page(daemon: LiveServer, browser) -> tuple[object, list[str]]:
    """The status page of ``daemon``, tracking, on a phone's screen, and its console's errors as they come."""
    daemon.wait_state("tracking", 60.0)
    browser_page = browser.new_page(viewport={"width": 390, "height": 844})
    console = watch_console(browser_page)
    browser_page.goto(daemon.base + "/")
    return browser_page, console


def canvas_labels(browser_page, canvas: str) -> list[str]:
    """The texts the canvas drew (web/plot.js keeps each with its box), checked to lie inside it and apart."""
    labels, size = browser_page.locator(canvas).evaluate("c => [c.labels || [], [c.clientWidth, c.clientHeight]]")
    for k, a in enumerate(labels):
        assert a["left"] >= 0 and a["top"] >= 0 and a["right"] <= size[0] and a["bottom"] <= size[1], (a, size)
        for b in labels[k + 1:]:
            apart = a["right"] <= b["left"] or b["right"] <= a["left"] or a["bottom"] <= b["top"] or \
                b["bottom"] <= a["top"]
            assert apart, (canvas, a, b)
    return [label["text"] for label in labels]


def test_the_sensor_map_is_drawn_along_the_pixels_with_its_sigma(tmp_path: Path, browser, calibrated) -> None:
    """``[daemon] engine = "estimator"`` with dust landing on the camera's window: the page's "Learned maps" card
    draws the sensor map along the pixels (gain and offset with their ±σ band), first saying honestly that
    nothing is learned, then where the widest mark is, how much and how sure; the print is drawn as this engine
    keeps it (its print map, nothing learned on it: the dust is on the window), today's texture not shown."""
    from playwright.sync_api import expect

    from graytrack.service.daemon.app import create_app
    from tests.service.test_sensor_map_store import LANDING, LANDS, LEARNED_SAMPLES, learn

    data = calibrated(tmp_path / "data")  # the daemon's first calibration, done: the dust lands after it
    with LiveServer(create_app(fast_settings(data, tables=LANDING, engine="estimator"))) as daemon:
        daemon.after_calibration(LANDS)  # the specks have landed while the stage rests
        browser_page, console = phone_page(daemon, browser)
        sensor, info = browser_page.locator("#sensor-map"), browser_page.locator("#sensor-map-info")
        expect(sensor).to_have_attribute("data-learned", "0", timeout=10_000)  # the stage rests: nothing resolved
        assert re.search(r"nothing learned on the sensor's side|\d+ pixel\(s\) set aside", info.text_content())
        empty = canvas_labels(browser_page, "#sensor-map")
        assert "nothing learned: as calibrated" in empty or \
            any(re.fullmatch(r"\d+ px set aside, not yet resolved", text) for text in empty), empty
        expect(browser_page.locator("#texture-along")).to_be_hidden()
        expect(browser_page.locator("#print-map-along")).to_be_visible()

        learned = learn(daemon)
        expect(sensor).not_to_have_attribute("data-learned", re.compile(r"^\d$"), timeout=10_000)
        assert int(sensor.get_attribute("data-learned")) >= LEARNED_SAMPLES <= learned["learned_samples"]
        expect(info).to_have_text(re.compile(r"^\d+ pixel\(s\) learned in \d+ mark\(s\) · widest at row 0, pixels "
                                             r"\d+–\d+: gain 0\.\d{3} ± 0\.\d{3}, offset -?\d+\.\d ± \d+\.\d gray"),
                                  timeout=10_000)
        drawn = canvas_labels(browser_page, "#sensor-map")
        assert {"gain", "offset", "pixel"} <= set(drawn), drawn
        assert not any("nothing learned" in text or "set aside" in text for text in drawn), drawn
        # the ±σ band is drawn: some pixel's gain band is wider than a line where the map is resolved
        widths = browser_page.evaluate("""() => fetch('/api/maps').then(r => r.json()).then(d =>
            d.sensor_map.learned.map(i => d.sensor_map.gain_sigma[i]))""")
        assert widths and all(0.0 < width < 0.1 for width in widths), widths
        # told apart: the window's dust is not learned on the print. A place the print carried away from a speck
        # may be held for a while (1 of 8 sessions, a node or two: docs/daemon.md) until its evidence lets it go as
        # the stage moves on, which the test waits for rather than catch it at one moment.

        def printed_apart():
            printed = daemon.get("/api/maps").json()["print_map"]
            return all(mark["nodes"] == 1 for mark in printed["marks"]) and len(printed["marks"]) <= 1

        wait_for(printed_apart, 20.0, "the print's map holding none of the window's dust",
                 show=lambda: daemon.get("/api/maps").json()["print_map"]["marks"])
        assert browser_page.evaluate("document.documentElement.scrollWidth") <= 390
        assert console == [], console

def test_the_print_map_is_drawn_along_the_target_with_its_sigma(tmp_path: Path, browser, calibrated) -> None:
    """``[daemon] engine = "estimator"`` with dust settling on the print: the "Learned maps" card draws the print's
    map along the target (each place's reflectance from 1 with its ±σ) and says where the widest mark is, how
    much and how sure, as the status card's print line does; nothing is learned on the sensor's side."""
    from playwright.sync_api import expect

    from graytrack.service.daemon.app import create_app
    from tests.service.test_print_map_store import LEARNED_MARKS, SETTLING, learn
    from tests.service.test_sensor_map_store import LANDS

    data = calibrated(tmp_path / "data")  # the daemon's first calibration, done: the dust settles after it
    with LiveServer(create_app(fast_settings(data, tables=SETTLING, engine="estimator"))) as daemon:
        daemon.after_calibration(LANDS)  # the specks have landed while the stage rests
        browser_page, console = phone_page(daemon, browser)
        printed, info = browser_page.locator("#print-map"), browser_page.locator("#print-map-info")
        # The stage rests: none of the specks decided (they wait as candidates; a speck darkens its place by a
        # quarter or more). A place the motion carried across the pixels before them may be: the print beyond the
        # stroke's end, seen in calibration at the field's last pixels only, holds one the calibrated model does not
        # (on a loaded machine, decided at rest on its travel at the sweep's end: x_w ≈ 13.8 mm, 1–3 % darker).
        kept = daemon.status()["print_map"]
        assert all(mark["reflectance"] > FAINT for mark in kept["shown"]), kept["shown"]
        # the page shows what the daemon holds (read again at each look: such a place may be decided meanwhile)
        seen: list = []

        def drawn_as_held() -> bool:
            seen[:] = [printed.get_attribute("data-marks"), daemon.status()["print_map"]["marks"]]
            return seen[0] == str(seen[1])

        wait_for(drawn_as_held, 10.0, "the page's print map as the daemon holds it", show=lambda: seen)
        kept = daemon.status()["print_map"]
        if not kept["marks"]:  # and the page says nothing is learned
            expect(info).to_have_text(re.compile(r"^(nothing learned on the print|\d+ place\(s\) set aside, none "
                                                 r"yet decided by the motion)"))
            empty = canvas_labels(browser_page, "#print-map")
            assert "nothing learned: as calibrated" in empty or \
                any(re.fullmatch(r"\d+ place\(s\) set aside, not yet decided", text) for text in empty), empty
        expect(browser_page.locator("#texture-along")).to_be_hidden()

        learned = learn(daemon)
        expect(printed).not_to_have_attribute("data-marks", re.compile(r"^[0-2]$"), timeout=10_000)
        assert int(printed.get_attribute("data-marks")) >= LEARNED_MARKS <= learned["marks"]
        line = re.compile(r"^\d+ mark\(s\) learned on the print · widest at x_w = \d+\.\d{3} mm \(\d+ µm\): "
                          r"reflectance 0\.\d{3} ± 0\.\d{3}")
        expect(info).to_have_text(line, timeout=10_000)
        expect(browser_page.locator("#texture")).to_have_text(line, timeout=10_000)  # the status card's line
        drawn = canvas_labels(browser_page, "#print-map")
        assert {"reflectance", "x_w (mm)"} <= set(drawn), drawn
        assert not any("nothing learned" in text for text in drawn), drawn
        # each resolved place's ±σ is drawn, and is a fraction of the light it takes
        resolved = browser_page.evaluate("""() => fetch('/api/maps').then(r => r.json()).then(d =>
            d.print_map.x_mm.map((_, i) => i).filter(i => d.print_map.learned[i])
              .map(i => [d.print_map.reflectance[i], d.print_map.reflectance_sigma[i]]))""")
        assert resolved and all(0.0 < sigma < 0.1 for _, sigma in resolved), resolved
        assert min(value for value, _ in resolved) < 0.9
        expect(browser_page.locator("#sensor-map")).to_have_attribute("data-learned", "0")
        assert browser_page.evaluate("document.documentElement.scrollWidth") <= 390
        assert console == [], console
