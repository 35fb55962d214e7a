"""What a report says when its figures are missing, how it states the grating's readout step, and
that no share of the residual is ever above 100 %."""

from __future__ import annotations

import dataclasses
import json
import math
import re

import numpy as np
import pytest

from graytrack.core.calibration import KIND_SPECS
from graytrack.core.calibration_data import calibration_data
from graytrack.core.diagnosis import diagnose, loop
from graytrack.core.diagnosis.loop import all_evidence
from graytrack.core.diagnosis.heldout import interleaved_split
from graytrack.core.geometry import initial_geometry
from graytrack.core.noise import reference_resolution_mm
from graytrack.core.recording import Recording
from graytrack.drivers.sim import paper
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.service.calibration_run import CalibrationRun, loop_lines, write_files
from graytrack.service.report import render_html
from tests.conftest import paper_recording

PERCENT = re.compile(r"(-?\d+(?:\.\d+)?)\s*%")
NOT_A_FIGURE = re.compile(r"\b(nan|None|inf)\b")


def _nothing_placed(stage: loop.LoopModel) -> loop.LoopModel:
    """The stage as a model that placed none of the held-out frames leaves it: no figure exists."""
    figures = dataclasses.replace(stage.figures, rmse_gray=math.nan, error_std_um=math.inf, error_max_um=math.inf,
                                  error_mean_um=math.nan, crlb_um=math.nan,
                                  error_um=np.full_like(stage.figures.error_um, np.nan))
    return dataclasses.replace(stage, figures=figures)


def _every_number(value, replacement):
    """``value`` (a report) with every number replaced (flags and counts as well: nothing may be trusted)."""
    if isinstance(value, dict):
        return {key: _every_number(item, replacement) for key, item in value.items()}
    if isinstance(value, list):
        return [_every_number(item, replacement) for item in value]
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return replacement
    return value


@pytest.fixture(scope="module")
def lost_everything():
    """A real loop result whose models then place none of the held-out frames, with σ unknown."""
    result = diagnose(paper_recording(n_frames=300, seed=7), max_steps=0)
    return dataclasses.replace(result, before=_nothing_placed(result.before), after=_nothing_placed(result.after),
                               sigma_gray=math.nan, reference_step_mm=0.0005)


def test_a_loop_that_placed_no_frame_writes_its_report_with_dashes(lost_everything, tmp_path):
    report = lost_everything.report()
    for key in ("rmse_gray", "error_std_um", "error_max_um", "error_mean_um"):
        assert report["before"][key] is None and report["after"][key] is None
    assert report["noise"]["gray"] is None and report["noise"]["crlb_um"] is None
    assert report["noise"]["floor_um"] is None  # √(bound² + step²/12) with no bound: no floor either
    json.dumps(report, allow_nan=False)  # what write_files does: no NaN reaches the file

    paths = write_files(CalibrationRun.of_diagnosis(lost_everything), tmp_path)
    page = paths["html"].read_text()
    assert "—" in page and "frames not placed" in page
    assert not NOT_A_FIGURE.search(page.split("<h2>Residual over")[0])  # the text, not the PNGs' base64
    lines = "\n".join(loop_lines(report))
    assert "n/a" in lines and not NOT_A_FIGURE.search(lines)


@pytest.mark.parametrize("missing", [None, math.nan])
def test_every_number_of_a_report_may_be_missing(lost_everything, missing):
    """The report page of the loop and of a plain fit, and the command line's summaries, on reports
    whose every number is gone."""
    run = CalibrationRun.of_diagnosis(lost_everything)
    run.report = report = _every_number(run.report, missing)
    page = render_html(run)
    assert page.count("—") >= 8
    assert not NOT_A_FIGURE.search(page.split("<h2>Residual over")[0])
    assert not NOT_A_FIGURE.search("\n".join(loop_lines(report)))

    daemon = {"model": "paper (M=5, P=3)", "rmse_gray": missing, "sigma_gray": missing, "iterations": missing,
              "frames": missing, "stroke_mm": missing, "period_mm": missing, "pixel_pitch_mm": missing,
              "held_out": {"error_std_um": missing, "bound_um": missing, "frames": missing, "method": "two-fold"}}
    plain = CalibrationRun("paper", lost_everything.final_model, daemon, None, None)
    page = render_html(plain)
    assert page.count("—") >= 8 and not NOT_A_FIGURE.search(page)
    assert not NOT_A_FIGURE.search("\n".join(plain.lines()))


def _stop_sweep(step_um: float = 256.5, stops: int = 41, per_stop: int = 5, seed: int = 9) -> Recording:
    """A step-and-settle sweep as the daemon records it: ``per_stop`` frames at rest at each stop, the
    grating read at 0.5 µm."""
    at = np.round(np.arange(stops) * step_um / 0.5) * 0.5e-3
    positions = np.repeat(at, per_stop)
    frames = paper.paper_frames(positions, rng=np.random.default_rng(seed))[:, 0, :].astype(np.float32)
    return Recording(frames, np.arange(positions.size) * 0.05, positions,
                     {"period_mm": paper.PERIOD_MM, "pixel_pitch_mm": paper.PIXEL_PITCH_MM})


def test_the_stops_held_out_are_no_readout_grid():
    """The held-out part of a stop sweep keeps stops one and seven stops apart: still the stops."""
    sweep = _stop_sweep()
    _, held = interleaved_split(calibration_data(sweep))
    assert np.diff(np.unique(held.x_mm)).max() > 1.5  # gaps of several stops
    assert reference_resolution_mm(sweep.reference) == 0.0
    assert reference_resolution_mm(held.x_mm) == 0.0


def test_a_stop_sweeps_diagnosis_claims_no_readout_floor():
    """The daemon's message: "The grating readout comes in steps of 256.500 µm: against it no sensor
    can show less than 74.061 µm" came from the held-out stops; the floor is the bound's."""
    result = diagnose(_stop_sweep(), max_steps=0)
    noise = result.report()["noise"]
    assert noise["reference_resolution_um"] == 0.0
    assert noise["floor_um"] == pytest.approx(noise["crlb_um"])
    assert "comes in steps" not in render_html(CalibrationRun.of_diagnosis(result))


def test_a_coarse_grating_under_stops_is_still_found():
    """Stops 256.5 µm apart read by a 50 µm grating (gaps of 250 and 300 µm): the 50 µm is the readout's."""
    sweep = _stop_sweep()
    coarse = np.round(sweep.reference / 0.05) * 0.05
    _, held = interleaved_split(calibration_data(dataclasses.replace(sweep, reference=coarse)))
    assert reference_resolution_mm(coarse) == pytest.approx(0.05)
    assert reference_resolution_mm(held.x_mm) == pytest.approx(0.05)


def _probed(recording: Recording):
    train, val = interleaved_split(calibration_data(recording))
    stage = loop._stage(KIND_SPECS["paper"], train, val, initial_geometry(train), refine_geometry=True)
    return all_evidence(stage)


@pytest.mark.parametrize("seed", [2, 4])
def test_no_probe_explains_more_than_all_or_less_than_none(seed):
    """A residual at the noise level (the paper model on the paper's field): a gain and offset per
    frame fitted to noise explained 451 % of its excess (seed 4); target maps −428 %."""
    for evidence in _probed(paper_recording(n_frames=400, seed=seed)):
        assert 0.0 <= evidence.share <= 1.0, (evidence.effect, evidence.share)
        assert all(0.0 <= float(p) <= 100.0 for p in PERCENT.findall(evidence.text)), evidence.text


def test_a_real_structure_still_takes_most_of_the_excess():
    """Flicker after the paper model: the per-frame gain accounts for nearly all the residual above noise."""
    recording, _ = build_rig("paper", "flicker:mains_hz=60:depth=0.03", seed=3).record(8.0)
    common = next(ev for ev in _probed(recording) if ev.effect == "common_mode")
    assert 0.8 < common.share <= 1.0
    assert "explain" in common.text and float(PERCENT.findall(common.text)[-1]) >= 80.0


def test_frames_of_a_jpeg_stream_are_named_with_the_bound_they_allow(tmp_path):
    """MJPEG at quality 75 on a 16-row strip: the report names the stream and the larger bound its
    quantisation leaves (the sensor-noise bound alone promises what such frames do not hold)."""
    recording, _ = build_rig("lab", "mjpeg:quality=75", seed=3).record(1.5)
    result = diagnose(recording, max_steps=0)
    report = result.report()
    found = report["findings"]["compression"]
    assert found["kind"] == "jpeg" and abs(found["quality"] - 75) <= 2
    assert found["crlb_um"] > 1.8 * report["noise"]["crlb_um"]
    assert "JPEG (MJPEG) stream" in render_html(CalibrationRun.of_diagnosis(result))
    assert any("JPEG stream" in line for line in loop_lines(report))
    plain, _ = build_rig("lab", seed=3).record(1.5)
    assert "compression" not in diagnose(plain, max_steps=0).report()["findings"]
