"""A lamp's flicker at twice the mains (core/estimator/state.py ``flicker_cos``, ``flicker_sin``): the frame's light
moved on from frame to frame by the flicker's turn over the interval (kernel.predict), the flicker read only through
the frame's light. A camera of 210 frames a second samples a 100 Hz flicker near its Nyquist rate: the light
alternates from frame to frame under a slow beat, and over less than a period of the print each frame's light held at
the lamp's mean moves the position with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graytrack.core.estimator import kernel
from graytrack.core.estimator.filter import Estimator, track
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.estimator.state import FC, FS, G, N_STATE, OFS
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model

FAST = "frame_rate:hz=210"  # the paper rig's camera at 210 frames/s (its own 50 alias a 100 Hz flicker to a constant)
DEPTH = 0.1  # a fluorescent tube's flicker, relative (a halogen's 1-3 % moves a paper frame a fifth as much)
EXPOSURE_S = 0.001  # the paper rig's


def test_the_frames_light_moves_on_by_the_flickers_turn_and_the_flicker_walks_by_its_depth():
    """``predict`` against F P Fᵀ + Q written out: the gain is the lamp's mean plus the flicker's parts times the
    cosine and the sine at the frame's time, so it moves by their change; each part's walk (its rate relative to the
    flicker's depth) enters the new frame's light by the new cosine or sine."""
    rng = np.random.default_rng(1)
    root = rng.normal(size=(N_STATE, N_STATE))
    P = 1e-4 * (root @ root.T + N_STATE * np.eye(N_STATE))
    s = rng.normal(size=N_STATE) * 0.01
    s[G] = 1.0
    rates2 = np.zeros(N_STATE)
    rates2[FC] = rates2[FS] = 0.3 ** 2
    before, cos_new, sin_new, dt = 0.7, math.cos(2.9), math.sin(2.9), 1.0 / 210
    flicker = np.array([cos_new - math.cos(before), sin_new - math.sin(before), cos_new, sin_new])
    F = np.eye(N_STATE)
    F[G, FC], F[G, FS] = flicker[0], flicker[1]
    walk = 0.5 * rates2[FC] * dt * (s[FC] ** 2 + s[FS] ** 2)
    Q = np.zeros((N_STATE, N_STATE))
    for part, trig in ((FC, cos_new), (FS, sin_new)):  # (the part's walk w: the part by w, the frame's light by trig·w)
        column = np.zeros(N_STATE)
        column[part], column[G] = 1.0, trig
        Q += walk * np.outer(column, column)
    expected_s, expected_P = F @ s, F @ P @ F.T + Q
    got_s, got_P = s.copy(), P.copy()
    held = np.zeros(N_STATE)  # (the other states' rates nought: only the flicker moves the light)
    held[FC] = held[FS] = rates2[FC]
    kernel.predict(got_s, got_P, dt, 0.0, 0.0, held, flicker)
    for state in (G, FC, FS, OFS):
        assert got_s[state] == pytest.approx(expected_s[state], abs=1e-15)
    light = [G, FC, FS, OFS]
    np.testing.assert_allclose(got_P[np.ix_(light, light)], expected_P[np.ix_(light, light)], rtol=1e-12, atol=1e-18)
    # a lamp without a flicker (its parts at nought, known) holds none: the frame's light does not walk
    quiet, quiet_P = s.copy(), np.zeros((N_STATE, N_STATE))
    quiet[FC] = quiet[FS] = 0.0
    quiet_P[FC, FC] = quiet_P[FS, FS] = 1e-30
    kernel.predict(quiet, quiet_P, dt, 0.0, 0.0, held, flicker)
    assert quiet_P[G, G] < 1e-28 and quiet[G] == 1.0


@pytest.fixture(scope="module")
def fast_model():
    """Calibrated under a lamp on DC (no flicker): the flicker comes with the run, undeclared."""
    return rig_model("paper", FAST, seed=3, seconds=10.0)


def _scored(model, effects: str, grating: str, settings: EstimatorSettings | None = None):
    run, truth = build_rig("paper", effects, seed=4, run=1).record(5.0)
    estimator = Estimator(model, settings=settings, grating=grating)
    estimates = track(model, run.frames, run.t, run.reference, estimator=estimator)
    error = np.array([e.x_mm for e in estimates]) - truth.x_mm
    if grating == "none":
        error -= model.period_mm * np.round(np.nanmedian(error) / model.period_mm)
    error *= 1e3
    bound = np.array([e.crlb_mm for e in estimates]) * 1e3
    stale = np.array([e.stale for e in estimates])
    placed = np.isfinite(error)
    silent = float(np.mean(placed & (np.abs(error) > 4 * bound) & ~stale))
    return float(np.nanstd(error)), silent, estimates


@pytest.mark.parametrize("grating", ["check", "none"])
def test_a_flickering_lamp_under_a_fast_camera_is_read_not_taken_for_the_position(fast_model, grating):
    steady, _, _ = _scored(fast_model, FAST, grating)
    flickering = f"{FAST},flicker:mains_hz=50:depth={DEPTH}:phase_deg=30"
    read, silent, estimates = _scored(fast_model, flickering, grating)
    unread, _, _ = _scored(fast_model, flickering, grating, EstimatorSettings(flicker_prior=0.0))
    assert read < 1.25 * steady and silent <= 0.005
    assert unread > 2.0 * read  # (the lamp's mean held: the frame's light off by the flicker, the position with it)
    # what the frames read of the flicker is the lamp's: its depth as the exposure averages it
    seen = DEPTH * abs(np.sinc(2 * 100.0 * EXPOSURE_S))
    late = np.array([math.hypot(e.state[FC], e.state[FS]) for e in estimates[len(estimates) // 2:]])
    assert np.median(late) == pytest.approx(seen, rel=0.2)


def test_a_frame_rate_that_holds_the_flickers_phase_leaves_it_unread_and_costs_nothing():
    """At 50 frames/s a 100 Hz flicker is sampled at one phase: no different from the lamp's mean, and no state
    of it moves (its parts keep their prior, the frame's light what the frames read)."""
    model = rig_model("paper", "", seed=3)
    run, truth = build_rig("paper", "", seed=4, run=1).record(5.0)
    on, off = (track(model, run.frames, run.t, run.reference, settings=EstimatorSettings(flicker_prior=prior))
               for prior in (0.02, 0.0))
    assert max(max(abs(e.state[FC]), abs(e.state[FS])) for e in on) < 1e-9  # (the phase's rounding: 1e-12)
    x_on, x_off = (np.array([e.x_mm for e in estimates]) for estimates in (on, off))
    np.testing.assert_allclose(x_on, x_off, rtol=0, atol=1e-9)


def test_track_follows_the_flicker_of_the_mains_it_is_told(fast_model, tmp_path, capsys):
    """``track --engine estimator --mains-hz``, or a recording's ``mains_hz``: the mains the lamp runs on, whose
    flicker at twice it the estimator follows (50 unless told; 0: a lamp on DC, none followed). A lamp on 50 Hz told
    to be on DC is read as the lamp's mean, and the positions with it; the flag overrides what the recording states.
    A bad frequency, or the flag without the estimator, is an error naming the flag."""
    import dataclasses

    from graytrack.core.models import save_model
    from graytrack.core.recording import MAINS_HZ, save
    from graytrack.service.cli import main
    from tests.tables import read_columns

    save_model(fast_model, tmp_path / "m.json")
    run, truth = build_rig("paper", f"{FAST},flicker:mains_hz=50:depth={DEPTH}:phase_deg=30", seed=4,
                           run=1).record(4.0)
    save(run, tmp_path / "run.npz")
    save(dataclasses.replace(run, meta={**run.meta, MAINS_HZ: 0.0}), tmp_path / "dc.npz")
    errors = {}
    for name, recording, extra in (("default", "run", []), ("dc", "run", ["--mains-hz", "0"]),
                                   ("stated", "dc", []), ("overridden", "dc", ["--mains-hz", "50"])):
        assert main(["track", str(tmp_path / f"{recording}.npz"), "--model", str(tmp_path / "m.json"), "--engine",
                     "estimator", "--out", str(tmp_path / f"{name}.csv"), *extra]) == 0
        columns = read_columns(tmp_path / f"{name}.csv")
        errors[name] = float(np.nanstd(columns["x_mm"] - truth.x_mm)) * 1e3
    assert errors["dc"] > 2.0 * errors["default"] and errors["stated"] > 2.0 * errors["default"], errors
    assert errors["overridden"] == pytest.approx(errors["default"], rel=1e-6)
    capsys.readouterr()
    common = ["track", str(tmp_path / "run.npz"), "--model", str(tmp_path / "m.json")]
    assert main([*common, "--engine", "estimator", "--out", str(tmp_path / "bad.csv"), "--mains-hz", "-5"]) != 0
    assert "--mains-hz" in capsys.readouterr().err
    assert main([*common, "--out", str(tmp_path / "w.csv"), "--mains-hz", "50"]) != 0
    assert "--engine estimator" in capsys.readouterr().err
