"""The library of effects the closed loop can add to a model.

Each effect is a small unit: what physical causes it stands for, what it adds to the model, how
that is fitted, and which residual probe (evidence.py) calls for it. Adding an effect to graytrack
means adding a probe and an entry here; the loop itself does not change.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from graytrack.core.structure import DEFAULT_MAP_STEPS, MAX_MAP_STEPS, ModelSpec

MAX_HARMONICS = 13
MAX_PIXEL_DEGREE = 9
MAX_STROKE_DEGREE = 8


@dataclass(frozen=True)
class Effect:
    name: str
    family: str  # the physical causes that leave this structure
    adds: str  # what the model gains
    fitted: str  # how the addition is fitted
    grow: Callable[[ModelSpec, Any], ModelSpec | None]  # None when it cannot grow any further

    def describe(self) -> dict[str, str]:
        return {"effect": self.name, "family": self.family, "adds": self.adds, "fitted": self.fitted}


def _more_harmonics(spec: ModelSpec, _: Any) -> ModelSpec | None:
    return spec.with_changes(harmonics=spec.harmonics + 2) if spec.harmonics + 2 <= MAX_HARMONICS else None


def _higher_pixel_degree(spec: ModelSpec, _: Any) -> ModelSpec | None:
    degree = spec.pixel_degree + 2
    return spec.with_changes(pixel_degree=degree) if degree <= MAX_PIXEL_DEGREE else None


def _stroke_terms(spec: ModelSpec, _: Any) -> ModelSpec | None:
    degree = spec.stroke_degree + 2
    return spec.with_changes(stroke_degree=degree) if degree <= MAX_STROKE_DEGREE else None


def _once(flag: str) -> Callable[[ModelSpec, Any], ModelSpec | None]:
    def grow(spec: ModelSpec, _: Any) -> ModelSpec | None:
        return None if getattr(spec, flag) else spec.with_changes(**{flag: True})

    return grow


def _finer_map(spec: ModelSpec, _: Any) -> ModelSpec | None:
    steps = 2 * spec.target_map if spec.target_map else DEFAULT_MAP_STEPS
    return spec.with_changes(target_map=steps) if steps <= MAX_MAP_STEPS else None


def _reference_skew(spec: ModelSpec, skew_s: Any) -> ModelSpec | None:
    return None if skew_s is None else spec.with_changes(reference_skew_s=spec.reference_skew_s + float(skew_s))


def _clip(spec: ModelSpec, limits: Any) -> ModelSpec | None:
    return None if spec.clip_gray is not None or limits is None else spec.with_changes(clip_gray=tuple(limits))


EFFECTS: dict[str, Effect] = {
    effect.name: effect
    for effect in (
        Effect("harmonics", "target profile not a pure sine (print gamma, print harmonics, sensor gamma, defocus)",
               "two more Fourier orders of the target phase", "linear coefficients, inside the variable projection",
               _more_harmonics),
        Effect("pixel_polynomial", "smooth variation across the field (vignetting, lens distortion, field-dependent blur)",
               "two more polynomial degrees in the pixel index", "linear coefficients, inside the variable projection",
               _higher_pixel_degree),
        Effect("stroke", "non-periodic variation along the stroke (illumination fixed to the target, print density, "
               "pitch error and chirp)", "coefficients that are polynomials of the stroke position (two more degrees)",
               "linear coefficients; tracking solves x through the x-dependent model", _stroke_terms),
        Effect("flat_field", "pixel-to-pixel response (PRNU gain, DSNU offset, dust on the sensor)",
               "a gain and an offset per pixel (the part the pixel polynomials cannot hold)",
               "alternating least squares with the smooth part", _once("flat_field")),
        Effect("common_mode", "light or exposure changing from frame to frame (flicker, auto-exposure, drift)",
               "a gain and an offset per frame", "alternating least squares in calibration; solved with x in tracking",
               _once("common_mode")),
        Effect("rows", "rows of the strip that disagree (camera tilt against the axis, row shading)",
               "one model per row: a target shift per row and row-dependent coefficients",
               "row shift inside the variable projection, row polynomials linear", _once("per_row")),
        Effect("target_map", "local defects fixed to the target (dust, scratches, print flaws)",
               "a relative reflectance map on a half-pixel grid along the target (its periodic part left to the "
               "Fourier terms)", "tridiagonal least squares, alternating with the smooth part; "
               "tracking uses its slope too; a second step halves the grid", _finer_map),
        Effect("reference_timing", "grating read at another instant than the exposure (latch skew, readout latency)",
               "the reference moved to mid-exposure: x(t) = ref(t) − v·δ (a correction of the data, kept in "
               "model.json as info.reference_skew_s)", "δ from the regression of the held-out error on velocity",
               _reference_skew),
        Effect("clipping", "sensor saturation or a black clip", "the clip limits: clipped samples carry no position",
               "clipped samples get zero weight in calibration and zero slope in tracking", _clip),
    )
}
