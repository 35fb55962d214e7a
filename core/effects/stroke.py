"""Coefficients that drift along the stroke: light fixed to the target, print density, chirp."""

from __future__ import annotations

from typing import Any

import numpy as np

from graytrack.core.effects import Effect
from graytrack.core.evidence import cross_validated_evidence, stroke_poly

MAX_STROKE_DEGREE = 8


def stroke_basis(fit: Any) -> np.ndarray:
    """Gain, offset and phase drifting along the stroke: [F, 1, F′] × P_j(x), j = 1..4."""

    poly = stroke_poly(fit)[:, None, None, :]
    parts = [fit.smooth[..., None] * poly, np.ones_like(fit.smooth)[..., None] * poly, fit.slope[..., None] * poly]
    return np.concatenate(parts, axis=-1)


class Stroke(Effect):
    name = "stroke"
    frame_part = "stroke"  # core/frame_tables.py: what tracking reads of it
    family = ("non-periodic variation along the stroke (illumination fixed to the target, print density, "
              "pitch error and chirp)")
    adds = "coefficients that are polynomials of the stroke position (two more degrees)"
    fitted = "linear coefficients; tracking solves x through the x-dependent model"
    order = 12

    def probe(self, stage):

        return cross_validated_evidence(self.name, "stroke position", stage, stroke_basis,
                                        "gain, offset or phase drifting along the stroke")

    def grow(self, spec, argument):
        degree = spec.stroke_degree + 2
        return spec.with_changes(stroke_degree=degree) if degree <= MAX_STROKE_DEGREE else None


EFFECT = Stroke()
