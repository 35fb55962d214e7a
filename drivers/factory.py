"""Build the camera and the stage from their configuration (what the daemon calls at start).

``kind`` names a registered driver (drivers/registry.py): a hardware one builds itself from its table
(``from_config``). ``kind = "sim"`` builds the virtual rig behind the *real* drivers: the stage is a
:class:`GCSStage` talking to a simulated controller over a pty, so the daemon exercises the same
code paths with and without hardware. A simulated camera needs the simulated stage (it renders
that stage's true position), so that combination is required.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from graytrack.drivers.camera.base import Camera
from graytrack.drivers.clock import REAL_TIME, ScaledClock
from graytrack.drivers.config import CameraConfig, ConfigError, HardwareConfig, StageConfig
from graytrack.drivers.registry import cameras, stages
from graytrack.drivers.stage.base import Stage
from graytrack.drivers.stage.gcs_stage import GCSStage

if TYPE_CHECKING:
    from graytrack.drivers.sim.rig import VirtualRig
    from graytrack.drivers.sim.stage import SimStage
    from graytrack.drivers.stage.sim_controller import SimGCSController


@dataclass
class Hardware:
    camera: Camera
    stage: Stage
    controller: object | None = None  # SimGCSController when simulated
    rig: object | None = None  # VirtualRig when simulated

    def close(self) -> None:
        self.camera.close()
        self.stage.close()
        if self.controller is not None:
            self.controller.stop()  # type: ignore[attr-defined]


def make_gcs_stage(config: StageConfig, port: str | None = None) -> GCSStage:
    return GCSStage.from_config(config, port)


def make_real_camera(config: CameraConfig) -> Camera:
    """The hardware camera ``kind`` names (Aravis's ``gi`` is only imported when one opens)."""
    driver = cameras.resolve(config.kind)
    if driver.simulated:
        raise ConfigError(f"camera.kind: {config.kind!r} is not a hardware camera")
    return driver.cls.from_config(config)  # type: ignore[attr-defined]


def make_real_stage(config: StageConfig) -> Stage:
    """The hardware stage ``kind`` names."""
    driver = stages.resolve(config.kind)
    if driver.simulated:
        raise ConfigError(f"stage.kind: {config.kind!r} is not a hardware stage")
    return driver.cls.from_config(config)  # type: ignore[attr-defined]


def open_hardware(config: HardwareConfig, clock: ScaledClock = REAL_TIME) -> Hardware:
    """Open camera and stage (stage referenced and ready); the caller closes the result."""
    camera_simulated = cameras.resolve(config.camera.kind).simulated
    stage_simulated = stages.resolve(config.stage.kind).simulated
    if camera_simulated and not stage_simulated:
        raise ConfigError(f"camera.kind = {config.camera.kind!r} renders the simulated stage: "
                          "set stage.kind = 'sim' too")
    if not stage_simulated:
        hardware = Hardware(make_real_camera(config.camera), make_real_stage(config.stage))
    else:
        hardware = _simulated(config, clock)
    try:
        hardware.stage.open()
        hardware.camera.open()
    except Exception:
        hardware.close()
        raise
    return hardware


def virtual_rig_controller(rig: VirtualRig, clock: ScaledClock = REAL_TIME, path: str | None = None
                           ) -> tuple[SimStage, SimGCSController]:
    """The virtual rig's stage (its true motion) and a simulated PI controller driving it, not yet started.

    The controller reports the rig's grating, as on the bench; ``path`` is where its pty is linked
    (a private temporary folder when None). What the daemon's virtual rig and
    ``graytrack sim-controller`` both run.
    """
    from graytrack.drivers.stage.sim_axis import SimStageAxis
    from graytrack.drivers.stage.sim_controller import SimGCSController

    truth = rig.make_stage(t_s=clock.now())
    return truth, SimGCSController(SimStageAxis(truth, rig.make_grating(truth)), path=path, clock=clock.now)


def _simulated(config: HardwareConfig, clock: ScaledClock) -> Hardware:
    from graytrack.drivers.camera.sim import SimCamera
    from graytrack.drivers.sim.scenarios import build_rig

    rig = build_rig(config.camera.scenario, config.camera.effects, seed=config.camera.seed)
    if cameras.resolve(config.camera.kind).simulated and config.camera.rig_process:
        # the stage's motion, its controller and the rendering in a process of their own (drivers/sim/process.py)
        from graytrack.drivers.sim.process import RigProcess

        source = RigProcess(rig, clock).start()  # RigProcessError says why it cannot
        assert source.path is not None
        return Hardware(SimCamera(rig, None, config.camera.to_settings(), clock=clock, source=source),
                        make_gcs_stage(config.stage, port=source.path), _Stopper(source), rig)
    truth, controller = virtual_rig_controller(rig, clock)
    controller.start()
    stage = make_gcs_stage(config.stage, port=controller.path)
    camera = (SimCamera(rig, truth, config.camera.to_settings(), clock=clock)
              if cameras.resolve(config.camera.kind).simulated else make_real_camera(config.camera))
    return Hardware(camera, stage, controller, rig)


class _Stopper:
    """``Hardware.controller`` for a rig process: ``stop()`` ends it (its controller goes with it)."""

    def __init__(self, process: object) -> None:
        self.process = process

    def stop(self) -> None:
        self.process.stop()  # type: ignore[attr-defined]
