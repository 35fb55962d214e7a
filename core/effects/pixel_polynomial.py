"""Higher pixel polynomials: smooth variation across the field of view."""

from __future__ import annotations

from typing import Any

import numpy as np

from graytrack.core.basis import legendre_basis, scaled, trig_basis
from graytrack.core.effects import Effect
from graytrack.core.evidence import cross_validated_evidence, trig_times_pixel

MAX_PIXEL_DEGREE = 9


def pixel_polynomial_basis(fit: Any) -> np.ndarray:
    """The model's trig terms times the next three pixel polynomials."""

    model = fit.model
    u = np.arange(model.n_pixels, dtype=np.float64)
    higher = legendre_basis(scaled(u, 0, model.n_pixels - 1), model.pixel_degree + 3)[:, model.pixel_degree + 1:]
    return trig_times_pixel(trig_basis(model.phase(fit.data.x_mm), model.harmonics), higher)


class PixelPolynomial(Effect):
    name = "pixel_polynomial"
    frame_part = "coefficients"  # core/frame_tables.py: what tracking reads of it
    family = "smooth variation across the field (vignetting, lens distortion, field-dependent blur)"
    adds = "two more polynomial degrees in the pixel index"
    fitted = "linear coefficients, inside the variable projection"
    order = 11

    def probe(self, stage):

        return cross_validated_evidence(self.name, "pixel index (smooth)", stage, pixel_polynomial_basis,
                                        f"pixel dependence beyond degree {stage.train.model.pixel_degree}")

    def grow(self, spec, argument):
        degree = spec.pixel_degree + 2
        return spec.with_changes(pixel_degree=degree) if degree <= MAX_PIXEL_DEGREE else None


EFFECT = PixelPolynomial()
