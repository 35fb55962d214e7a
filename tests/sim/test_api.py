"""The virtual rig's public API: scenarios, effect specs, determinism, truth kept apart, the CLI."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from graytrack.core.recording import load
from graytrack.drivers.sim.effects import EFFECTS, EffectError, parse_effects
from graytrack.drivers.sim.rig import Truth
from graytrack.drivers.sim.scenarios import ScenarioError, build_rig, list_effects, list_scenarios
from graytrack.service.cli import main

HERE = Path(__file__).parent


def test_every_effect_has_a_signature_test():
    sources = "".join(p.read_text() for p in HERE.glob("test_effects_*.py"))
    used = set(re.findall(r'"([a-z_0-9]+)(?::[^"]*)?"', sources))
    missing = sorted(set(EFFECTS) - used)
    assert not missing, f"effects without a signature test: {missing}"


def test_listings_name_scenarios_and_document_parameters():
    scenarios, effects = list_scenarios(), list_effects()
    assert {"paper", "clean", "strip16"} <= set(scenarios)
    assert len(effects) >= 25
    for name, eff in EFFECTS.items():
        for param in eff.params:
            assert f"{param.name}=" in effects[name]


def test_effect_specs_parse_with_defaults_and_continuations():
    parsed = parse_effects(["flicker:mains_hz=60,depth=0.1,tilt", ("prnu", {"sigma": 0.03})])
    assert [(e.name, v) for e, v in parsed][:2] == [
        ("flicker", {"mains_hz": 60.0, "depth": 0.1, "phase_deg": -1.0}), ("tilt", {"deg": 0.5})]
    assert parsed[2][1] == {"sigma": 0.03}
    for bad, message in [("nope", "unknown effect"), ("tilt:angle=1", "no parameter 'angle'"),
                         ("tilt:deg=abc", "not a number"), ("depth=3", "before any effect"), ("tilt:deg", "key=value"),
                         ("quantize:bits=40", "1..16"), ("dropped_frames:p=1", "[0, 1)")]:
        with pytest.raises(EffectError, match=re.escape(message)):
            build_rig("clean", [bad])
    with pytest.raises(ScenarioError, match="unknown scenario"):
        build_rig("nope")


def test_same_seed_same_recording_other_seed_other_noise():
    effects = ["prnu", "dust", "flicker", "jitter", "dropped_frames"]
    a, ta = build_rig("clean", effects, seed=7).record(1.0)
    b, tb = build_rig("clean", effects, seed=7).record(1.0)
    c, _ = build_rig("clean", effects, seed=8).record(1.0)
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.reference, b.reference)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(ta.pixel_gain, tb.pixel_gain)
    assert a.frames.shape != c.frames.shape or not np.array_equal(a.frames, c.frames)


def test_switching_an_effect_on_keeps_the_other_random_parts():
    plain = build_rig("clean", ["prnu"], seed=3)
    more = build_rig("clean", ["prnu", "dust", "flicker"], seed=3)
    np.testing.assert_array_equal(plain.sensor.prnu, more.sensor.prnu)
    a, _ = build_rig("clean", [], seed=3).record(0.2)
    b, _ = build_rig("clean", ["time_skew:ms=1"], seed=3).record(0.2)
    np.testing.assert_array_equal(a.frames, b.frames)


def test_render_accepts_still_and_exposure_samples():
    rig = build_rig("strip16", seed=1)
    still = rig.render(np.array([1.0, 2.0]), np.array([0.0, 0.02]))
    moving = rig.render(np.array([[1.0, 1.1], [2.0, 2.1]]), np.array([0.0, 0.02]))
    assert still.shape == moving.shape == (2, 16, 100) and still.dtype == np.float32
    with pytest.raises(ValueError):
        rig.render(np.zeros((2, 3)), np.zeros(3))


def test_recording_meta_and_truth_kept_apart(tmp_path):
    rig = build_rig("paper", ["tilt:deg=0.1"], seed=2)
    rec, truth = rig.record(1.0)
    assert rec.frames.shape == (50, 100) and rec.frames.dtype == np.float32
    assert rec.meta["pixel_pitch_mm"] == 0.062 and rec.meta["period_mm"] == 8.62
    assert rec.meta["scenario"] == "paper" and rec.meta["effects"] == ["tilt:deg=0.1"] and rec.meta["seed"] == 2
    assert "bit_depth" not in rec.meta  # float32 gray field, no digitiser
    assert np.abs(rec.reference - truth.x_mm).max() <= 0.00025 + 1e-12
    assert np.all(np.diff(truth.x_mm) > 0)
    path = truth.save(tmp_path / "truth.npz")
    again = Truth.load(path)
    np.testing.assert_array_equal(again.x_mm, truth.x_mm)
    assert again.period_mm == truth.period_mm and again.info["effects"] == ["tilt:deg=0.1"]


def test_cli_simulate_writes_recording_and_truth_beside_it(tmp_path, capsys):
    out, truth_path = tmp_path / "rec.npz", tmp_path / "truth.npz"
    code = main(["simulate", "--scenario", "clean", "--seconds", "0.5", "--effects", "flicker:depth=0.1",
                 "--effects", "prnu", "--seed", "5", "--truth", str(truth_path), "--out", str(out)])
    assert code == 0
    rec = load(out)
    assert rec.n_frames == 25 and rec.meta["effects"][0].startswith("flicker:")
    with np.load(out) as archive:
        assert sorted(archive.files) == ["frames", "meta", "reference", "t"]
        meta = json.loads(str(archive["meta"]))
    assert not {"x_mm", "truth", "light_gain"} & set(meta)
    truth = Truth.load(truth_path)
    assert truth.x_mm.shape == (25,) and truth.light_gain.std() > 0


@pytest.mark.parametrize("argv, message", [
    (["simulate", "--scenario", "nope", "--out", "x.npz"], "unknown scenario 'nope'"),
    (["simulate", "--effects", "tilt:deg=x", "--out", "x.npz"], "not a number"),
    (["simulate", "--seconds", "0", "--out", "x.npz"], "--seconds must be positive"),
    (["simulate"], "--out REC.npz is required"),
])
def test_cli_bad_input_is_one_line_and_exit_2(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
    assert not (tmp_path / "x.npz").exists()


def test_cli_list_names_scenarios_and_effects(capsys):
    assert main(["simulate", "--list"]) == 0
    text = capsys.readouterr().out
    for name in list(list_scenarios()) + list(EFFECTS):
        assert name in text
    assert "NAME[:KEY=VALUE" in text


def test_another_run_of_the_same_rig_keeps_its_fixed_patterns_and_draws_new_noise():
    first, truth_first = build_rig("paper", "prnu:sigma=0.02,bad_pixels", seed=3).record(2.0)
    again, _ = build_rig("paper", "prnu:sigma=0.02,bad_pixels", seed=3).record(2.0)
    other, truth_other = build_rig("paper", "prnu:sigma=0.02,bad_pixels", seed=3, run=1).record(2.0)
    np.testing.assert_array_equal(first.frames, again.frames)
    np.testing.assert_array_equal(truth_first.pixel_gain, truth_other.pixel_gain)
    noise = other.frames.astype(float) - first.frames.astype(float)
    assert 0.8 < np.std(noise) / np.sqrt(2 * 0.7**2) < 1.2  # two independent draws of σ = 0.7
