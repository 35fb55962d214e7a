"""Drivers by name: ``kind`` names a registered class, its dotted path or a short name; a new driver is
its own module, registering itself, with no edit to config.py or factory.py; an unknown name is refused
listing the known ones."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import pytest

from graytrack.drivers import registry
from graytrack.drivers.camera.aravis import AravisCamera
from graytrack.drivers.camera.opencv import OpenCVCamera
from graytrack.drivers.camera.sim import SimCamera
from graytrack.drivers.config import ConfigError, parse_hardware
from graytrack.drivers.factory import make_real_camera, make_real_stage
from graytrack.drivers.registry import Registry
from graytrack.drivers.stage.gcs_stage import GCSStage
from graytrack.drivers.stage.sim_controller import SimGCSController

# A camera kept outside the repository: one module, registering itself where it is defined.
LINE_CAMERA = '''
import numpy as np

from graytrack.drivers.camera.base import Camera, Frame
from graytrack.drivers.registry import cameras


@cameras.register("ramp")
class RampCamera(Camera):
    """Frame k is the ramp 0..cols-1 plus k: what a test can check pixel by pixel."""

    @classmethod
    def from_config(cls, config):
        return cls(config.to_settings(), cols=config.roi.cols)

    def __init__(self, settings, cols):
        super().__init__(settings)
        self.cols, self.k = cols, 0

    def _open_device(self):
        self.k = 0

    def _close_device(self):
        pass

    def _apply_settings(self):
        pass

    def _read(self, timeout_s):
        self.k += 1
        return Frame(np.arange(self.cols, dtype=np.uint16)[None] + self.k, self.k, float(self.k))
'''


@pytest.fixture
def own_registrations(monkeypatch: pytest.MonkeyPatch) -> None:
    """What a test registers leaves with it (the registries are the process's)."""
    for shared in (registry.cameras, registry.stages):
        shared.known()  # discovered before the copy, so the copy holds the repository's drivers
        monkeypatch.setattr(shared, "_by_name", dict(shared._by_name))


@pytest.mark.parametrize(("name", "cls", "kind"), [
    ("opencv", OpenCVCamera, "opencv"),
    ("OpenCVCamera", OpenCVCamera, "opencv"),
    ("graytrack.drivers.camera.opencv.OpenCVCamera", OpenCVCamera, "opencv"),
    ("aravis", AravisCamera, "aravis"),
    ("AravisCamera", AravisCamera, "aravis"),
    ("sim", SimCamera, "sim"),
    ("SimCamera", SimCamera, "sim"),
])
def test_a_camera_is_named_by_its_class_its_path_or_its_short_name(name: str, cls: type, kind: str) -> None:
    driver = registry.cameras.resolve(name)
    assert driver.cls is cls and driver.name == kind
    # the table reads back the short name the rest of the daemon compares against
    config = parse_hardware({"camera": {"kind": name, "device": 0}, "stage": {"kind": "sim"}})
    assert config.camera.kind == kind


@pytest.mark.parametrize(("name", "cls", "kind"), [
    ("gcs", GCSStage, "gcs"), ("GCSStage", GCSStage, "gcs"), ("sim", SimGCSController, "sim"),
    ("SimGCSController", SimGCSController, "sim"),
])
def test_a_stage_is_named_the_same_ways(name: str, cls: type, kind: str) -> None:
    assert registry.stages.resolve(name).cls is cls
    assert parse_hardware({"stage": {"kind": name, "port": "/dev/ttyUSB0"}}).stage.kind == kind


def test_an_unknown_name_is_refused_listing_the_known_ones() -> None:
    with pytest.raises(ConfigError) as camera:
        parse_hardware({"camera": {"kind": "webcam"}})
    assert str(camera.value) == ("camera.kind: unknown camera 'webcam'; known: aravis (AravisCamera), "
                                 "opencv (OpenCVCamera), sim (SimCamera)")
    with pytest.raises(ConfigError, match=r"^stage\.kind: unknown stage 'Gcs'; known: gcs \(GCSStage\), "
                                          r"sim \(SimGCSController\)$"):
        parse_hardware({"stage": {"kind": "Gcs"}})
    with pytest.raises(ConfigError, match=r"camera\.kind: camera 'mylab\.Cam': cannot import mylab"):
        parse_hardware({"camera": {"kind": "mylab.Cam"}})


def test_the_hardware_builders_refuse_a_simulated_driver() -> None:
    config = parse_hardware({})
    with pytest.raises(ConfigError, match="'sim' is not a hardware camera"):
        make_real_camera(config.camera)
    with pytest.raises(ConfigError, match="'sim' is not a hardware stage"):
        make_real_stage(config.stage)


def test_the_builders_read_the_table() -> None:
    config = parse_hardware({"camera": {"kind": "AravisCamera", "device": 7, "trigger": "hardware",
                                        "pixel_format": "Mono12", "n_buffers": 4, "readout_us": 250.0},
                             "stage": {"kind": "GCSStage", "port": "/dev/ttyUSB3", "baudrate": 57600, "axis": "2",
                                       "soft_limits_mm": [1.0, 9.0], "velocity_mm_s": 2.5}})
    camera = make_real_camera(config.camera)  # built, not opened: no Aravis needed
    assert isinstance(camera, AravisCamera)
    assert (camera.device_id, camera.trigger, camera.pixel_format) == ("7", "hardware", "Mono12")
    assert camera.readout_s == pytest.approx(250e-6)
    stage = make_real_stage(config.stage)
    assert isinstance(stage, GCSStage) and stage.axis == "2" and stage.limits() == (1.0, 9.0)


def test_a_new_camera_is_one_module_registering_itself(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       own_registrations: None) -> None:
    package = tmp_path / "mylab_cameras"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "ramp.py").write_text(textwrap.dedent(LINE_CAMERA))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "mylab_cameras.ramp", raising=False)
    # named by its dotted path: importing the module registers it; from then on its short name works too
    config = parse_hardware({"camera": {"kind": "mylab_cameras.ramp.RampCamera", "roi": {"cols": 5}}, "stage":
                             {"kind": "gcs", "port": "/dev/ttyUSB0"}})
    assert config.camera.kind == "ramp"
    assert parse_hardware({"camera": {"kind": "RampCamera"}}).camera.kind == "ramp"
    with make_real_camera(config.camera) as camera:
        frames = [camera.read().pixels for _ in range(3)]
    assert [frame.tolist() for frame in frames] == [[[1, 2, 3, 4, 5]], [[2, 3, 4, 5, 6]], [[3, 4, 5, 6, 7]]]


def test_a_name_is_one_drivers(own_registrations: None) -> None:
    class OtherOpenCV:
        pass

    with pytest.raises(ValueError, match="camera name 'opencv' is graytrack.drivers.camera.opencv.OpenCVCamera's"):
        registry.cameras.register("opencv")(OtherOpenCV)
    assert registry.cameras.resolve("opencv").cls is OpenCVCamera


def test_a_driver_that_cannot_load_is_named_with_its_reason(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    package = tmp_path / "bench_stages"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "needs_vendor.py").write_text("import vendor_sdk_that_is_not_installed\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("bench_stages", "bench_stages.needs_vendor"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    stages = Registry("stage", "bench_stages")
    with pytest.raises(LookupError) as error:
        stages.resolve("vendor")
    assert str(error.value) == ("unknown stage 'vendor'; known: none; not loaded: bench_stages.needs_vendor "
                                "(No module named 'vendor_sdk_that_is_not_installed')")
