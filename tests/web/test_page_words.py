"""The status page explains its words where they stand, shows a stale model at the position, groups
repeated events, and lays out at 390 px without an overlap (issue 48, item 6), in real headless
Chromium against a daemon serving on loopback with its data in the test's folder.

The layout is judged from the boxes the browser computed (getBoundingClientRect) and, inside the
plots, from the box of every text the canvas drew (``canvas.labels``, kept by web/plot.js)."""

from __future__ import annotations

import re
from itertools import combinations
from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.service.helpers import LiveServer, fast_settings, wait_for
from tests.web.conftest import CHROMIUM
from tests.web.test_status_page import watch_console

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed (apt-get install chromium)")
NARROW = {"width": 390, "height": 844}
# the words a newcomer asked about (issue 48) and where each stands on the page
WORDS = {"lock": ".figures dt[data-term=lock]", "grating": ".figures dt[data-term=grating]",
         "error": ".figures dt[data-term=error]", "bound": ".figures dt[data-term=bound]",
         "stale": "#position-stale", "print texture": "#texture-card h2",
         "frames lost": ".figures dt[data-term=dropped]"}
REPEATS = 12  # frames_lost events in a row, as a loaded host logs them (one per 10 s)
BOX = "e => { const r = e.getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; }"


def overlap(a: list[float], b: list[float]) -> float:
    """The area two boxes [left, top, right, bottom] share (px²)."""
    return max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))


@pytest.fixture
def stale_on_demand(monkeypatch: pytest.MonkeyPatch) -> dict[str, bool]:
    """The live tracker's frames flagged stale (cause: focus) while ``flag["stale"]``: the validity
    monitor's verdict, as tests/service/test_history.py drives it."""
    from graytrack.core import tracking

    real_update, flag = tracking.LiveTracker.update, {"stale": False}

    def update(self, frame, reference_mm=float("nan"), t=None):
        fix = real_update(self, frame, reference_mm, t)
        cause = "focus" if flag["stale"] else None
        return SimpleNamespace(**{**vars(fix), "stale": flag["stale"], "stale_reason": cause})

    monkeypatch.setattr(tracking.LiveTracker, "update", update)
    return flag


def test_the_words_are_explained_stale_shows_at_the_position_and_repeats_are_grouped_at_390_px(
        tmp_path: Path, browser, stale_on_demand, calibrated) -> None:
    from playwright.sync_api import expect

    from graytrack.service.daemon.app import create_app

    with LiveServer(create_app(fast_settings(calibrated(tmp_path / "data")))) as daemon:
        daemon.wait_state("tracking", 60.0)
        page = browser.new_page(viewport=NARROW)
        console = watch_console(page)
        page.goto(daemon.base + "/")
        expect(page.locator("#position")).to_have_text(re.compile(r"^\d+\.\d{4}$"), timeout=10_000)
        expect(page.locator("#grating")).to_have_text(re.compile(r"^\d+\.\d{4} mm$"), timeout=10_000)
        expect(page.locator("#history tbody tr")).to_have_count(1, timeout=10_000)

        # every word has its explanation where it stands, and the same one in the glossary
        glossary = dict(zip(page.locator("#glossary dt").all_text_contents(),
                            page.locator("#glossary dd").all_text_contents()))
        for word, selector in WORDS.items():
            title = page.locator(selector).get_attribute("title")
            assert title and title == glossary[word], (word, title)
        assert "Cramér–Rao bound" in glossary["bound"] and "standard deviation" in glossary["bound"]
        assert "recalibrate" in glossary["stale"]
        for term in page.locator("[data-term]").all():
            assert term.get_attribute("title"), term.evaluate("e => e.outerHTML")

        # a stale model is shown where the position is read, with its cause, and goes when it holds again
        flag = page.locator("#position-stale")
        expect(flag).to_be_hidden()
        stale_on_demand["stale"] = True
        expect(flag).to_have_text("stale: focus", timeout=10_000)
        expect(flag).to_be_visible()
        expect(page.locator("#model-stale")).to_contain_text("focus", timeout=10_000)  # the header says it too
        # both boxes from one layout (measured apart, the header's alert appearing between the two calls moved
        # the flag 37 px down from a position measured before it)
        position, shown = page.evaluate(f"() => [document.querySelector('#position'), "
                                        f"document.querySelector('#position-stale')].map({BOX})")
        # beside the number, or just under it where a long cause wraps (`stale: magnification` at 390 px)
        assert position[1] < shown[3] and shown[1] < position[3] + 8, ("at the position", position, shown)
        assert overlap(position, shown) == 0 and shown[2] <= NARROW["width"], (position, shown)
        stale_on_demand["stale"] = False
        expect(flag).to_be_hidden(timeout=10_000)
        wait_for(lambda: "model_fresh" in [e["kind"] for e in daemon.get("/api/events").json()], 10.0,
                 "the stale episode logged to its end")  # before the repeats, so that nothing splits them

        # repeated events: one line with their count; the calibration and the model installed still in view
        for n in range(REPEATS):
            daemon.rig.event("frames_lost", f"{n + 1} camera frame lost (test)")
        grouped = page.locator("#events li").first
        expect(grouped).to_have_attribute("data-kind", "frames_lost", timeout=10_000)
        expect(grouped).to_have_attribute("data-count", re.compile(r"^\d+$"))
        wait_for(lambda: int(grouped.get_attribute("data-count")) >= REPEATS, 10.0, "the repeats grouped")
        seen: dict = {}

        def as_logged() -> bool:
            """The page's events as the log has them (a real frame loss may be logged between the page's poll and
            this read: the page shows it at its next poll)."""
            seen["events"] = events = daemon.get("/api/events").json()
            seen["count"] = count = int(grouped.get_attribute("data-count"))
            tail = len(events) - max(i for i, e in enumerate(events) if e["kind"] != "frames_lost") - 1
            seen["counts"] = [int(c) for c in page.locator("#events li").evaluate_all(
                "items => items.map(li => li.dataset.count)")]
            # the frames_lost events in a row, all in the one line, and every event on a line
            return count == tail and sum(seen["counts"]) == len(events)

        wait_for(as_logged, 10.0, "the page's events to be the log's", show=lambda: seen)
        events, count = seen["events"], seen["count"]
        expect(grouped.locator(".count")).to_have_text(f"×{count}")
        expect(grouped.locator(".text")).to_have_text(events[-1]["message"])  # the newest
        lines = page.locator("#events li")
        assert lines.count() < len(events) - REPEATS + 2, (seen["counts"], len(events))
        kinds = lines.evaluate_all("items => items.map(li => li.dataset.kind)")
        for kind in ("calibration_done", "model_installed"):
            line = page.locator(f"#events li[data-kind={kind}]")
            expect(line).to_have_count(1)
            assert line.get_attribute("data-count") == "1"
            newer = len(events) - 1 - [e["kind"] for e in events].index(kind)  # events logged after it
            assert kinds.index(kind) <= newer - (REPEATS - 1), "the repeats above it take one line"

        # 390 px: nothing beyond the screen's width, no two key boxes on each other
        assert page.evaluate("document.documentElement.scrollWidth") <= NARROW["width"]
        figures = page.locator(".figures > *").evaluate_all(f"items => items.map({BOX})")
        line = page.locator(".position-line > *").evaluate_all(f"items => items.map({BOX})")
        for a, b in combinations(figures, 2):
            assert overlap(a, b) == 0, (a, b)
        for a, b in combinations(line, 2):
            assert overlap(a, b) == 0, (a, b)
        for dd in page.locator(".figures dd").all():  # one line each: "10.3600 mm" does not wrap
            height, line_height = dd.evaluate("e => [e.getBoundingClientRect().height, "
                                              "parseFloat(getComputedStyle(e).lineHeight)]")
            assert height < 1.5 * line_height, (dd.text_content(), height, line_height)
        model = page.locator("#history tbody tr td").nth(3)  # the model's name, the fourth cell
        expect(model).to_be_visible()
        cells = page.locator("#history tbody tr td").evaluate_all(f"items => items.map({BOX})")
        assert all(0 <= box[0] and box[2] <= NARROW["width"] for box in cells), cells
        for a, b in combinations(cells, 2):
            assert overlap(a, b) == 0, (a, b)
        for canvas in ("#plot", "#profile"):
            page.locator(canvas).scroll_into_view_if_needed()
            wait_for(lambda: page.locator(canvas).evaluate("c => (c.labels || []).length") > 4, 10.0, "drawn")
            labels, size = page.locator(canvas).evaluate("c => [c.labels, [c.clientWidth, c.clientHeight]]")
            assert any(label["text"] in ("mm", "gray") for label in labels)
            for a, b in combinations(labels, 2):
                boxes = [[x["left"], x["top"], x["right"], x["bottom"]] for x in (a, b)]
                assert overlap(*boxes) == 0, (canvas, a, b)
            assert all(x["left"] >= 0 and x["top"] >= 0 and x["right"] <= size[0] and x["bottom"] <= size[1]
                       for x in labels), (canvas, labels, size)
        page.screenshot(path=str(tmp_path / "page-390.png"), full_page=True)
        assert console == [], console


WEB = Path(__file__).resolve().parents[2] / "web"


@pytest.mark.parametrize("width", [390, 1200])
def test_no_axis_label_runs_into_another_when_a_tick_sits_on_the_plots_top_edge(browser, width: int) -> None:
    """The worst case for an axis's unit: data whose range ends exactly on a tick, so that tick's number
    is drawn centred on the box's top edge, right under the unit (where they collided)."""
    page = browser.new_page(viewport={"width": width, "height": 600})
    page.set_content('<canvas id="plot" style="width:100%;height:260px"></canvas>'
                     '<canvas id="profile" style="width:100%;height:260px"></canvas>')
    page.add_script_tag(path=str(WEB / "plot.js"))
    # position: half the frames at 0, half at 1/1.15 mm: the range with its 15 % margins is
    # [−0.13, 1.0] and its top tick 1.0 at the edge; error the same in µm × 10 (the right axis)
    edge = 1 / 1.15
    labels = page.evaluate("""edge => {
        const samples = Array.from({length: 200},
                                   (_, i) => ({t: i / 20, x: i % 2 ? edge : 0, e: i % 2 ? 10 * edge : 0}));
        Plot.timeSeries(document.getElementById("plot"), samples, 10, 10);
        // the line view: gray 0…200/1.08 (its 8 % pad puts 200 on the edge), residual within ±σ
        const n = 100, top = 200 / 1.08;
        const pixels = Array.from({length: n}, (_, i) => i % 2 ? top : 0);
        Plot.profile(document.getElementById("profile"), {pixels, model: pixels, residual: pixels.map(() => 0.1),
                                                          sigma: pixels.map(() => 0.7), saturated: [], bad: []});
        return [document.getElementById("plot").labels, document.getElementById("profile").labels];
    }""", edge)
    plot, profile = labels
    assert {"1.0", "mm", "10", "µm"} <= {x["text"] for x in plot}, plot  # the ticks on the edges are drawn
    assert {"200", "gray", "residual", "pixel"} <= {x["text"] for x in profile}, profile
    for drawn in (plot, profile):
        for a, b in combinations(drawn, 2):
            boxes = [[x["left"], x["top"], x["right"], x["bottom"]] for x in (a, b)]
            assert overlap(*boxes) == 0, (a, b)
        assert all(x["top"] >= 0 and x["left"] >= 0 for x in drawn), drawn
