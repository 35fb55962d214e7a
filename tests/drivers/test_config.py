"""Hardware configuration: the example file parses; mistakes are refused naming their key."""

from __future__ import annotations

from pathlib import Path

import pytest

from graytrack.drivers.camera.base import Roi
from graytrack.drivers.config import ConfigError, load_hardware, parse_hardware

EXAMPLE = Path(__file__).resolve().parents[2] / "deploy" / "graytrack.example.toml"


def test_example_config_parses_into_typed_settings() -> None:
    config = load_hardware(EXAMPLE)
    assert config.camera.kind == "aravis" and config.stage.kind == "gcs"
    settings = config.camera.to_settings()
    assert settings.roi == Roi(row=480, rows=16, col=320, cols=128)
    assert settings.exposure_us == 500.0 and settings.frame_rate_hz == 200.0 and config.camera.readout_us == 0.0
    assert config.stage.soft_limits_mm == (0.0, 20.0) and config.stage.baudrate == 115200


def test_defaults_are_the_virtual_rig() -> None:
    config = parse_hardware({"server": {"port": 8000}})
    assert config.camera.kind == "sim" and config.stage.kind == "sim"


@pytest.mark.parametrize(
    ("tables", "message"),
    [
        ({"camera": {"exposure": 5}}, "camera.exposure: unknown key"),
        ({"camera": {"kind": "webcam"}}, "camera.kind"),
        ({"camera": {"kind": "opencv"}}, "device is required"),
        ({"camera": {"exposure_us": -1}}, "camera.exposure_us"),
        ({"camera": {"roi": {"rows": 0}}}, "camera.roi.rows"),
        ({"camera": {"trigger": "software"}}, "needs kind = 'aravis'"),
        ({"stage": {"kind": "gcs"}}, "port is required"),
        ({"stage": {"baudrate": 12345}}, "stage.baudrate: must be one of"),
        ({"stage": {"soft_limits_mm": [5, 1]}}, "stage.soft_limits_mm: low must be below high"),
    ],
)
def test_mistakes_are_refused_naming_the_key(tables: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        parse_hardware(tables)


def test_unreadable_files_are_config_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera\nkind = 1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_hardware(bad)
    with pytest.raises(ConfigError, match="no such file"):
        load_hardware(tmp_path / "missing.toml")


def test_default_config_opens_the_virtual_rig_behind_the_real_drivers() -> None:
    from graytrack.drivers.factory import open_hardware

    hardware = open_hardware(parse_hardware({"stage": {"velocity_mm_s": 20.0}}))
    try:
        assert "simulated" in hardware.stage.identify()
        hardware.stage.move_to(0.5)
        assert hardware.stage.wait_on_target(2.0).position_mm == pytest.approx(0.5, abs=1e-3)
        frame = hardware.camera.read(1.0)
        assert frame.pixels.shape == (1, 100)
    finally:
        hardware.close()


def test_sim_camera_without_sim_stage_is_refused() -> None:
    from graytrack.drivers.factory import open_hardware

    with pytest.raises(ConfigError, match="stage.kind = 'sim'"):
        open_hardware(parse_hardware({"stage": {"kind": "gcs", "port": "/dev/null"}}))
