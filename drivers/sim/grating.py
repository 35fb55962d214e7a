"""The reference: a grating ruler on the stage, read by the controller.

Its reading differs from the true position by quantisation (``resolution_mm``, 0.5 µm as in the
paper), an interpolation ("cyclic") error periodic in the grating's signal period, and latency —
the value available at time t describes the stage at ``t − latency``. When a frame's reference is
latched at a different instant from the exposure (time skew, see timing.py), the reference error is
the distance travelled in between: proportional to velocity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from graytrack.drivers.sim.stage import ArrayLike, Trajectory


@dataclass
class GratingConfig:
    resolution_mm: float = 0.0005
    latency_s: float = 0.0
    cyclic_amplitude_mm: float = 0.0
    cyclic_period_mm: float = 0.02  # the grating's signal period (20 µm is common)
    cyclic_phase_rad: float = 0.0


class GratingReadout:
    """Reads a :class:`Trajectory` (usually a ``SimStage``) the way a grating ruler does."""

    def __init__(self, stage: Trajectory, config: GratingConfig | None = None):
        self.stage = stage
        self.config = config if config is not None else GratingConfig()

    def read(self, t_s: ArrayLike) -> np.ndarray:
        """Position in mm reported at time(s) ``t_s`` (quantised, with cyclic error and latency)."""
        cfg = self.config
        x = np.asarray(self.stage.position(np.asarray(t_s, dtype=np.float64) - cfg.latency_s), dtype=np.float64)
        if cfg.cyclic_amplitude_mm:
            x = x + cfg.cyclic_amplitude_mm * np.sin(2 * math.pi * x / cfg.cyclic_period_mm + cfg.cyclic_phase_rad)
        if cfg.resolution_mm > 0:
            x = cfg.resolution_mm * np.round(x / cfg.resolution_mm)
        return x
