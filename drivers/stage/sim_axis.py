"""The virtual rig's stage as the axis a simulated GCS controller moves.

The controller then reports the rig's grating readout (quantised, possibly late or with cyclic
error, as the scenario says) while the simulated camera renders the stage's true position: the
same split as on the bench, where ``POS?`` is a measurement, not the truth.
"""

from __future__ import annotations

from graytrack.drivers.sim.grating import GratingReadout
from graytrack.drivers.sim.stage import SimStage


class SimStageAxis:
    """Adapts :class:`SimStage` + :class:`GratingReadout` to :class:`~.axis_model.AxisModel`."""

    def __init__(self, stage: SimStage, grating: GratingReadout) -> None:
        self.stage = stage
        self.grating = grating

    @property
    def travel_mm(self) -> tuple[float, float]:
        return self.stage.soft_limits_mm

    def move_to(self, target_mm: float, t: float) -> None:
        self.stage.move_to(target_mm, t)

    def stop(self, t: float) -> None:
        self.stage.stop(t)

    def set_velocity(self, velocity_mm_s: float) -> None:
        self.stage.set_velocity(velocity_mm_s)

    def velocity_setting(self) -> float:
        return self.stage.velocity_mm_s

    def target(self) -> float:
        return self.stage.target_mm

    def readout(self, t: float) -> float:
        return float(self.grating.read(t))

    def on_target(self, t: float) -> bool:
        return self.stage.on_target(t)
