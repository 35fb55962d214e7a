"""Configuration, storage and grating pairing: the daemon's small parts on their own."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest

from graytrack.core.errors import ModelError
from graytrack.drivers.config import ConfigError
import numpy as np

from graytrack.service.daemon.grating import Readings
from graytrack.service.daemon.settings import default_data_dir, load_settings
from graytrack.service.daemon.storage import Storage

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "deploy" / "graytrack.example.toml"


def test_the_example_config_is_valid_and_the_default_is_the_virtual_rig() -> None:
    example = load_settings(EXAMPLE)
    assert example.hardware.camera.kind == "aravis" and not example.simulated
    assert example.daemon.host == "127.0.0.1" and example.sweep.model == "auto"
    opencv = load_settings(ROOT / "deploy" / "graytrack.opencv.toml")
    assert opencv.hardware.camera.kind == "opencv" and opencv.hardware.camera.device == 0 and not opencv.simulated
    assert opencv.daemon.auto_calibrate == "never"
    default = load_settings(None)
    assert default.simulated and default.daemon.host == "127.0.0.1" and default.daemon.port == 8000
    assert default.with_overrides(port=9000, host=None).daemon.port == 9000


def test_unknown_keys_and_tables_are_named(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text("[daemon]\nprot = 8000\n")
    with pytest.raises(ConfigError, match=r"daemon\.prot: unknown key"):
        load_settings(path)
    path.write_text("[sweep]\nmodel = 'ideal'\n")
    with pytest.raises(ConfigError, match=r"sweep\.model"):
        load_settings(path)


def test_data_dir_follows_systemd_then_xdg(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "state"))
    assert default_data_dir() == tmp_path / "state"
    monkeypatch.delenv("STATE_DIRECTORY")
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    assert default_data_dir() == tmp_path / "xdg" / "graytrack"


def test_token_is_generated_once_with_mode_0600_and_ids_sort_by_time(tmp_path: Path) -> None:
    storage = Storage(tmp_path)
    token, created = storage.token()
    assert created and len(token) >= 32 and stat.S_IMODE(storage.token_path.stat().st_mode) == 0o600
    assert storage.token() == (token, False)
    ids = [storage.new_calibration_id() for _ in range(5)]
    assert ids == sorted(ids) and len(set(ids)) == 5
    with pytest.raises(KeyError):
        storage.calibration_dir("../../etc")
    assert storage.load_current_model() is None
    storage.model_path.write_text("{not json")
    with pytest.raises(ModelError, match="not a JSON model file"):  # the rig turns it into a fault with this reason
        storage.load_current_model()


def _readings(t: np.ndarray, x: np.ndarray, latency_s: float = 0.0) -> Readings:
    readings = Readings(window_s=0.02, tolerance_mm=1e-3, rest_s=0.05)
    for ti, xi in zip(t, x):
        readings.append(float(ti), float(xi), latency_s)
    return readings


def test_grating_pairing_interpolates_straight_motion_and_refuses_acceleration() -> None:
    t = np.arange(0.0, 0.1, 0.005)
    moving = _readings(t, 2.0 + 10.0 * t)  # 10 mm/s, polled every 5 ms
    assert moving.at(0.0425) == pytest.approx(2.425, abs=1e-12), "bracketed: interpolated"
    assert np.isnan(moving.at(0.2)), "after the last reading of a moving stage: unknown"
    assert np.isnan(moving.at(-0.01)), "before the first reading: unknown"
    # accelerating at 2000 mm/s^2: a straight line between readings 5 ms apart is 6 um off
    accelerating = _readings(t, 1000.0 * t**2)
    assert np.isnan(accelerating.at(0.0425))
    gentle = _readings(t, 10.0 * t**2)  # 20 mm/s^2: 0.06 um error, below the tolerance
    assert gentle.at(0.0425) == pytest.approx(10.0 * 0.0425**2, abs=1e-4)
    sparse = _readings(np.array([0.0, 0.05, 0.1, 0.15]), np.array([0.0, 0.5, 1.0, 1.5]))
    assert np.isnan(sparse.at(0.075)), "readings further apart than the window do not bracket"
    # replies 0.3 ms after the request: at 10 mm/s the stamps are uncertain by 1.5 um, over the tolerance
    assert np.isnan(_readings(t, 2.0 + 10.0 * t, latency_s=3e-4).at(0.0425))
    assert _readings(t, 2.0 + 1.0 * t, latency_s=3e-4).at(0.0425) == pytest.approx(2.0425), "slower: 0.15 um"


def test_grating_pairing_holds_a_resting_stage_until_a_command() -> None:
    t = np.arange(0.0, 0.02, 0.005)
    resting = _readings(t, np.full(t.size, 3.0))
    assert resting.at(t[-1] + 0.004) == 3.0, "at rest, the newest reading holds for a frame just after it"
    assert resting.at(t[-1] + 0.04) == 3.0, "for longer than the bracketing window: a closed-loop axis holds"
    assert np.isnan(resting.at(t[-1] + 0.06)), "not for longer than rest_s (a stalled poller)"
    resting.note_command(t[-1] + 0.001)
    assert np.isnan(resting.at(t[-1] + 0.004)), "a move was commanded since: the stage may be moving"
    creeping = _readings(t, 3.0 + 0.01 * np.arange(t.size))
    assert np.isnan(creeping.at(t[-1] + 0.004)), "readings that disagree are not rest"


def test_grating_pairing_after_a_command_waits_for_the_stage_to_move_or_to_hold() -> None:
    """Readings of the old position just after a move command (the stage has not started yet), then a
    poller starved on a busy host: a frame exposed meanwhile was paired with the old position while
    the stage ran (a lock re-acquired a period away, on the daemon's virtual rig under load)."""
    readings = _readings(np.arange(0.0, 0.02, 0.005), np.full(4, 8.0))
    readings.note_command(0.0175)
    for t in (0.018, 0.023, 0.028):  # POS? answered before the stage started, then silence
        readings.append(t, 8.0)
    assert np.isnan(readings.at(0.04)), "the stage may be under way: no reference"
    for t in (0.033, 0.038):  # ... it moves, then stops at its target: the rest it reached
        readings.append(t, 7.5)
    for t in (0.043, 0.048, 0.053):
        readings.append(t, 7.0)
    assert readings.at(0.06) == 7.0
    held = _readings(np.arange(0.0, 0.02, 0.005), np.full(4, 3.0))
    held.note_command(0.0175)  # a stop at rest, a move to where it is: nothing moves
    for t in (0.018, 0.023, 0.028):
        held.append(t, 3.0)
    assert np.isnan(held.at(0.03)), "within rest_s of the command the old position proves nothing yet"
    for t in (0.058, 0.063, 0.068):
        held.append(t, 3.0)
    assert held.at(0.07) == 3.0, "held for rest_s after it: at rest"


def _paired_on_a_real_move(change_mm_s2: float) -> tuple[int, int]:
    """References sent and those off by more than the 1 um tolerance, over 40 moves of the simulated stage
    (accelerate, turn into deceleration, settle) read by a poller that is sometimes late (12 and 19 ms
    between readings, as on a busy host), each frame paired as the frame loop pairs it: when it arrives,
    with at most one reading after its exposure; scored against the stage's own position."""
    from graytrack.drivers.sim.stage import SimStage, SimStageConfig

    rng = np.random.default_rng(7)
    sent = far = 0
    for _ in range(40):
        stage = SimStage(SimStageConfig(velocity_mm_s=20.0))  # ACC = DEC = 100 mm/s^2: a 200 mm/s^2 reversal
        command_t = float(rng.uniform(0.0, 0.05))
        stage.move_to(4.0, command_t)
        polls = np.cumsum(rng.choice([0.005, 0.005, 0.005, 0.012, 0.019], size=100))
        truth = stage.position(polls)
        readings = Readings(window_s=0.02, tolerance_mm=1e-3, rest_s=0.25, change_mm_s2=change_mm_s2)
        seen = 0
        for t in np.sort(rng.uniform(0.0, 0.6, 200)):
            while seen < polls.size and polls[seen - 1 if seen else 0] <= t:  # up to the first reading after t
                if polls[seen] > command_t > readings.command_t:
                    readings.note_command(command_t)
                readings.append(float(polls[seen]), float(truth[seen]))
                seen += 1
            value = readings.at(float(t))
            if value == value:
                sent += 1
                far += abs(value - float(stage.position(t))) > 1e-3
    return sent, far


def test_grating_pairing_is_never_off_by_more_than_its_tolerance_on_a_real_move() -> None:
    sent, far = _paired_on_a_real_move(200.0)
    assert far == 0, f"{far} of {sent} references off by more than 1 um"
    trusting, wrong = _paired_on_a_real_move(0.0)  # one side's velocity change taken as all there is
    assert wrong > 0.005 * trusting, "the motion must reach what one side cannot see"
    assert sent > 0.9 * trusting, (sent, trusting)  # what it costs: the frames a late reading left unpaired


def test_make_run_installs_only_what_running_needs(tmp_path: Path) -> None:
    import re
    import subprocess

    dry = subprocess.run(["make", "-n", "run", f"VENV={tmp_path / 'venv'}"], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    installs = [line for line in dry.splitlines() if "pip install" in line and "--upgrade pip" not in line]
    assert len(installs) == 1 and re.search(r'-e "?\.', installs[0]), dry
    extras = re.search(r"\[([^\]]*)\]", installs[0])
    assert extras is None or "test" not in extras.group(1).split(","), "no pytest, no playwright for running"
    service = subprocess.run(["make", "-n", "service-venv", f"PREFIX={tmp_path / 'opt'}"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout
    assert f"-m venv {tmp_path / 'opt'}/.venv" in service and " -e " not in service, "the service venv is not editable"
