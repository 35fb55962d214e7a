"""More Fourier orders of the target phase: a profile that is not a pure sine."""

from __future__ import annotations

from typing import Any

import numpy as np

from graytrack.core.basis import trig_basis
from graytrack.core.effects import Effect
from graytrack.core.evidence import cross_validated_evidence, trig_times_pixel

MAX_HARMONICS = 13
PROBE_ORDERS = 4  # orders beyond the model's that the probe looks at


def harmonic_basis(fit: Any) -> np.ndarray:
    """Harmonics above the model's order, times the first two pixel polynomials."""

    model = fit.model
    trig = trig_basis(model.phase(fit.data.x_mm), model.harmonics + PROBE_ORDERS)[..., 2 * model.harmonics + 1:]
    return trig_times_pixel(trig, model.pixel_basis()[:, :2])


class Harmonics(Effect):
    name = "harmonics"
    frame_part = "coefficients"  # core/frame_tables.py: what tracking reads of it
    family = "target profile not a pure sine (print gamma, print harmonics, sensor gamma, defocus)"
    adds = "two more Fourier orders of the target phase"
    fitted = "linear coefficients, inside the variable projection"
    order = 10

    def probe(self, stage):

        m = stage.train.model.harmonics
        return cross_validated_evidence(self.name, "target phase", stage, harmonic_basis,
                                        f"harmonics {m + 1}–{m + PROBE_ORDERS} of the target phase")

    def grow(self, spec, argument):
        return spec.with_changes(harmonics=spec.harmonics + 2) if spec.harmonics + 2 <= MAX_HARMONICS else None


EFFECT = Harmonics()
