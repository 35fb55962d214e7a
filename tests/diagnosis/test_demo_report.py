"""The demo's report (`graytrack demo`: the seed paper's table on the paper rig, then the closed loop on
a rig with effects it is not told about) says each thing once: one name for the bound and one value
per model, τ once, the injected effects listed, the before and after panels on one y-scale, log-axis
ticks as plain numbers. It holds the ideal/paper table the terminal shows, and the figures README.md
and docs/performance.md quote are the ones it holds (the demo is seeded: every run prints the same)."""

from __future__ import annotations

import contextlib
import html
import io
import json
import re
from pathlib import Path

import pytest

from graytrack.service.commands.demo import UNDECLARED_EFFECTS, make_demo
from graytrack.service.report import _panels, error_figure, residual_spread

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory):
    """The demo itself, with its default seed, as `graytrack demo` runs it (the report, the run, what it printed)."""
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        run, paths = make_demo(tmp_path_factory.mktemp("demo"), seed=0)
    page = paths["html"].read_text()
    text = html.unescape(re.sub(r"<[^>]+>", " ", re.sub(r'src="data:[^"]*"', "", page.split("</style>")[1])))
    return run, re.sub(r"\s+", " ", text), json.loads(Path(paths["json"]).read_text()), page, printed.getvalue()


def test_the_bound_has_one_name_and_each_model_one_value(demo) -> None:
    run, text, report, _, _ = demo
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
    run, text, _, _, _ = demo
    assert text.count("τ") == 1 and f"τ = {run.model.period_mm:.4f} mm" in text
    terminal = "\n".join(run.lines())
    assert terminal.count("τ") == 1 and f"τ={run.model.period_mm:.4f} mm" in terminal


def test_the_injected_effects_are_in_the_report_beside_what_the_loop_added(demo) -> None:
    run, text, report, _, _ = demo
    injected = report["recording"]["simulated_effects"]
    told = [spec.split(":")[0] for spec in UNDECLARED_EFFECTS.split(",")]
    assert [effect.split(":")[0] for effect in injected] == told
    for effect in injected:
        assert effect in text
    added = ", ".join(step["effect"].replace("_", " ") for step in report["steps"])
    assert f"The loop added: {added}." in text


def test_the_panels_share_one_y_scale_and_log_ticks_read_as_plain_numbers(demo) -> None:
    run, _, _, _, _ = demo
    before, after = error_figure(_panels(run)).axes
    assert before.get_ylim() == after.get_ylim()
    figure = residual_spread(run.diagnosis)
    figure.canvas.draw()
    labels = [label.get_text() for label in figure.axes[0].get_yticklabels() if label.get_text()]
    assert labels and all(re.fullmatch(r"\d+(\.\d+)?", label) for label in labels), labels


def quoted(figure: str, value: float) -> bool:
    """``figure`` as a doc quotes it is ``value`` rounded to the decimals quoted."""
    decimals = len(figure.partition(".")[2])
    return f"{value:.{decimals}f}" == figure


def test_the_report_holds_the_ideal_and_paper_models_table_the_terminal_prints(demo) -> None:
    _, text, report, page, printed = demo
    rows = {row["kind"]: row for row in report["seed_table"]["rows"]}
    assert list(rows) == ["ideal", "paper"]
    ideal, paper = rows["ideal"], rows["paper"]
    assert ideal["error_std_um"] > 10 * paper["error_std_um"] and paper["error_std_um"] < 1.1 * paper["bound_um"]
    assert ideal["paper"]["error_std_um"] == 56.4 and paper["paper"]["error_std_um"] == 1.5  # the paper's Table 1-2
    body = re.search(r'<table id="seed-table">(.*?)</table>', page, re.S).group(1)
    cells = [re.findall(r"<td>(.*?)</td>", tr) for tr in re.findall(r"<tr>(.*?)</tr>", body)[1:]]
    for row, shown_row in zip((ideal, paper), cells):
        assert shown_row[1:6] == [f"{row['rmse_gray']:.3f}", f"{row['period_mm']:.4f}", f"{row['error_mean_um']:.2f}",
                                  f"{row['error_std_um']:.3f}", f"{row['bound_um']:.3f}"], shown_row
        terminal = next(line for line in printed.splitlines() if line.strip().startswith(f"{row['kind']:<6} rmse"))
        assert f"± {row['error_std_um']:7.3f} um (bound {row['bound_um']:.3f} um)" in terminal  # the same figures
    assert "The seed paper's rig: ideal sine and the paper's model" in text


def test_the_readme_and_the_performance_page_quote_the_demos_figures(demo) -> None:
    _, _, report, _, _ = demo
    rows = {row["kind"]: row for row in report["seed_table"]["rows"]}
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    ideal = re.search(r"^\| seed paper's rig, ideal sine model \| ([\d.]+) µm \(paper", readme, re.M).group(1)
    paper = re.search(r"^\| seed paper's rig, the paper's Fourier × polynomial model \| ([\d.]+) µm at a ([\d.]+) µm "
                      "noise floor", readme, re.M).groups()
    assert quoted(ideal, rows["ideal"]["error_std_um"]), (ideal, rows["ideal"])
    assert quoted(paper[0], rows["paper"]["error_std_um"]) and quoted(paper[1], rows["paper"]["bound_um"]), paper
    performance = (ROOT / "docs" / "performance.md").read_text(encoding="utf-8")
    for kind, label in (("ideal", "ideal sine"), ("paper", "seed paper's model")):
        figures = re.search(rf"^\| {label} \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|", performance, re.M).groups()
        row = rows[kind]
        assert all(map(quoted, figures, (row["rmse_gray"], row["error_std_um"], row["bound_um"]))), (figures, row)
    loop = re.search(r"`graytrack demo` prints the combined case on a recording of its own: ([\d.]+) → ([\d.]+) µm "
                     r"against a ([\d.]+) µm bound", performance).groups()
    figures = (report["before"]["error_std_um"], report["after"]["error_std_um"], report["noise"]["crlb_um"])
    assert all(map(quoted, loop, figures)), (loop, figures)


def test_a_model_that_placed_no_frame_is_null_in_the_report_and_a_dash_on_the_page() -> None:
    from graytrack.core.seed_table import TableRow
    from graytrack.service.report import _seed_table

    nan = float("nan")
    row = TableRow("ideal", 8.0, 8.6, nan, nan, nan, placed=0, frames=500).as_dict()
    assert json.loads(json.dumps(row, allow_nan=False))["error_std_um"] is None  # never NaN in report.json
    page = _seed_table({"seed_table": {"protocol": "p", "scenario": "paper", "seed": 0, "calibration_frames": 1000,
                                       "measured_frames": 500, "rows": [row]}})
    cells = re.findall(r"<td>(.*?)</td>", page)
    assert cells[:8] == ["ideal sine", "8.000", "8.6000", "—", "—", "—", "500", "7.825"], cells
