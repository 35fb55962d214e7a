"""Configuration, storage and grating pairing: the daemon's small parts on their own."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest

from graytrack.drivers.config import ConfigError
from graytrack.drivers.stage.base import PositionReading
from graytrack.service.daemon.grating import pair_reading
from graytrack.service.daemon.settings import default_data_dir, load_settings
from graytrack.service.daemon.storage import Storage

EXAMPLE = Path(__file__).resolve().parents[2] / "deploy" / "graytrack.example.toml"


def test_the_example_config_is_valid_and_the_default_is_the_virtual_rig() -> None:
    example = load_settings(EXAMPLE)
    assert example.hardware.camera.kind == "aravis" and not example.simulated
    assert example.daemon.host == "127.0.0.1" and example.sweep.model == "paper"
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
    assert storage.load_current_model() is None, "a broken model file is ignored, not fatal"


def test_grating_readings_are_paired_by_time() -> None:
    readings = [PositionReading(1.0, 0.00, 0.001), PositionReading(2.0, 0.01, 0.001), PositionReading(2.0, 0.02, 0.001)]
    assert pair_reading(readings, 0.005, 0.05) == pytest.approx(1.5)  # bracketed: interpolated
    assert pair_reading(readings, 0.025, 0.05) == pytest.approx(2.0)  # after the last: extrapolated
    assert pair_reading(readings[:1], 0.01, 0.05) == 1.0  # one reading close enough
    assert pair_reading(readings, 1.0, 0.05) != pair_reading(readings, 1.0, 0.05)  # none near: NaN
    assert pair_reading([], 0.0, 0.05) != pair_reading([], 0.0, 0.05)
