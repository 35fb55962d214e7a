"""A calibration's report.html (service/report.py on service/report_kit.py) in real headless Chromium:
every plot decodes, the kit's stylesheet applies, and the headline reads the held-out figures of
report.json under the one name "bound"."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from graytrack.service.calibration_run import calibrate_recording, write_files
from tests.diagnosis.test_held_out_validation import _stops
from tests.web.conftest import CHROMIUM
from tests.web.test_status_page import watch_console

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed (apt-get install chromium)")


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The daemon's default kind (the seed paper's model) on a 21-stop sweep, its files written."""
    return write_files(calibrate_recording(_stops(seed=5, effects=""), "paper"), tmp_path_factory.mktemp("report"))


def test_the_report_page_renders_its_plot_and_states_the_held_out_figures(written, browser) -> None:
    report = json.loads(written["json"].read_text())
    held = report["held_out"]
    page = browser.new_page()
    errors = watch_console(page)
    page.goto(written["html"].as_uri())
    sizes = page.eval_on_selector_all("img", "images => images.map(image => [image.naturalWidth, image.naturalHeight])")
    assert len(sizes) == 1 and all(width > 300 and height > 100 for width, height in sizes), sizes
    assert page.eval_on_selector("table", "table => getComputedStyle(table).borderCollapse") == "collapse"
    headline = page.inner_text("p.big")
    assert f"held-out error std {held['error_std_um']:.3f} µm" in headline
    assert f"bound {held['bound_um']:.3f} µm" in headline and "noise floor" not in page.inner_text("body")
    assert errors == []
