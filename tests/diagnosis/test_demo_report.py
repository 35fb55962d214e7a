"""The demo's report (`graytrack demo`: the closed loop on a rig with effects it is not told about)
says each thing once: one name for the bound and one value per model, τ once, the injected effects
listed, the before and after panels on one y-scale, log-axis ticks as plain numbers."""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

import pytest

from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.calibration_run import CalibrationRun, calibrate_recording, write_files
from graytrack.service.commands.demo import UNDECLARED_EFFECTS
from graytrack.service.report import _panels, error_figure, residual_spread

SECONDS = 8.0  # the demo records 20 s; 8 s (400 frames) show the same effects, found by the same steps


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[CalibrationRun, str, dict]:
    recording, _ = build_rig("paper", UNDECLARED_EFFECTS, seed=0).record(SECONDS)
    run = calibrate_recording(recording, "auto")
    paths = write_files(run, tmp_path_factory.mktemp("demo"))
    page = paths["html"].read_text()
    text = html.unescape(re.sub(r"<[^>]+>", " ", re.sub(r'src="data:[^"]*"', "", page.split("</style>")[1])))
    return run, re.sub(r"\s+", " ", text), json.loads(Path(paths["json"]).read_text())


def test_the_bound_has_one_name_and_each_model_one_value(demo) -> None:
    run, text, report = demo
    assert report["steps"], "the loop found none of the injected effects"
    assert "noise floor" not in text and "CRLB" not in text and text.count("Cramér–Rao") == 1
    before, after = report["before"]["crlb_um"], report["after"]["crlb_um"]
    assert after == report["noise"]["crlb_um"]
    stated = set(re.findall(r"bound:? (\d+\.\d+) µm", text)) | set(re.findall(r"(\d+\.\d+) µm for the", text))
    assert stated <= {f"{before:.3f}", f"{after:.3f}"} and f"{after:.3f}" in stated, (stated, before, after)
    assert f"readout floor √(bound² + step²/12) = {report['noise']['floor_um']:.3f} µm" in text
    terminal = "\n".join(run.lines())  # what `graytrack demo` prints: the same names and values
    assert f"Cramer-Rao bound {after:.3f} um" in terminal
    assert f"readout floor {report['noise']['floor_um']:.3f} um" in terminal
    figure = error_figure(_panels(run))
    titles = [ax.get_title() for ax in figure.axes]
    assert titles == [f"before (seed paper's model): error std {report['before']['error_std_um']:.3f} µm, "
                      f"bound {before:.3f} µm",
                      f"after the loop: error std {report['after']['error_std_um']:.3f} µm, bound {after:.3f} µm"]


def test_tau_is_stated_once_for_the_model_written(demo) -> None:
    run, text, _ = demo
    assert text.count("τ") == 1 and f"τ = {run.model.period_mm:.4f} mm" in text
    terminal = "\n".join(run.lines())
    assert terminal.count("τ") == 1 and f"τ={run.model.period_mm:.4f} mm" in terminal


def test_the_injected_effects_are_in_the_report_beside_what_the_loop_added(demo) -> None:
    run, text, report = demo
    injected = report["recording"]["simulated_effects"]
    told = [spec.split(":")[0] for spec in UNDECLARED_EFFECTS.split(",")]
    assert [effect.split(":")[0] for effect in injected] == told
    for effect in injected:
        assert effect in text
    added = ", ".join(step["effect"].replace("_", " ") for step in report["steps"])
    assert f"The loop added: {added}." in text


def test_the_panels_share_one_y_scale_and_log_ticks_read_as_plain_numbers(demo) -> None:
    run, _, _ = demo
    before, after = error_figure(_panels(run)).axes
    assert before.get_ylim() == after.get_ylim()
    figure = residual_spread(run.diagnosis)
    figure.canvas.draw()
    labels = [label.get_text() for label in figure.axes[0].get_yticklabels() if label.get_text()]
    assert labels and all(re.fullmatch(r"\d+(\.\d+)?", label) for label in labels), labels
