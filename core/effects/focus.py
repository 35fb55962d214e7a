"""Focus (blur) changing from frame to frame: a lens mount warming up, a camera breathing.

A Gaussian blur of variance δ on the target multiplies harmonic m of the profile by
exp(−2π² δ (m/τ)²), so a small change of focus adds δ·B to every pixel, with B = ∂S/∂δ =
−2π²/τ² Σ m²·(harmonic m of S): one number per frame, physically parameterised, that neither a
gain (which scales every order alike, the mean level too) nor a light field can stand for.

Calibration: when the frames show it, one δ per frame is fitted by alternation with the smooth
model (whose harmonics then describe the calibration's mean focus: the δ are centred), so the
model is the target at one focus rather than a blend. Tracking needs nothing from it: the
tracker's own focus term (core/focus_solve.py) measures δ against the model's focus in every
frame that asks. The spread of the calibration's δ goes into the model's info, in px², for the
focus watch to know what the model was calibrated at.
"""

from __future__ import annotations

import numpy as np

from graytrack.core.effects import Effect
from graytrack.core.models.fourier import TWO_PI, FourierModel
from graytrack.core.evidence import Evidence, explains, share_above_noise, z_beyond_noise


def blur_direction(model: FourierModel, x_mm: np.ndarray) -> np.ndarray:
    """``(K, R, n)`` ∂S/∂δ of the smooth model at frame positions ``x_mm``: each harmonic of the
    target phase times −2π²(m/τ)² (gray per mm² of blur variance)."""
    trig = model.trig(x_mm)  # (K, R, n, 2M+1): constant, then sin and cos of each order
    stroke, _ = model.stroke_basis(np.asarray(x_mm, dtype=np.float64))
    orders = np.r_[0, np.repeat(np.arange(1, model.harmonics + 1), 2)]
    factor = -0.5 * (TWO_PI / model.period_mm) ** 2 * orders**2
    return model.sum_terms(trig * factor, model.frame_weights(stroke))


def per_frame_blur(target: np.ndarray, direction: np.ndarray,
                   weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares δ per frame of ``target ≈ δ·direction`` (all ``(K, R, n)``), and the sum of
    squares each frame's δ removes (second return)."""
    wd = weights * direction
    norm = np.maximum((wd * direction).sum(axis=(1, 2)), 1e-300)
    delta = (wd * target).sum(axis=(1, 2)) / norm
    return delta, delta * delta * norm


FOCUS_INFO = "focus_per_frame"  # the model's info flag: calibrated with a change of focus per frame


class Focus(Effect):
    name = "focus"
    frame_part = "per-frame unknowns"  # core/frame_tables.py: what tracking reads of it
    family = "focus changing during the calibration (a lens mount warming up, a camera breathing)"
    adds = "a change of blur per frame, δ·∂S/∂δ (each harmonic m attenuated by exp(−2π²δ(m/τ)²))"
    fitted = "alternating least squares with the smooth model; measured per frame again in tracking"
    order = 32  # after the common mode: what a gain per frame leaves, the blur may explain
    bilinear = True
    # A focus drifting during the sweep is correlated with x; before its layer is known, the
    # smooth model's period takes part of it (a scale error of a few hundred ppm): refined again.
    refits_geometry = True

    def probe(self, stage):
        """One δ per held-out frame, fitted on those frames themselves (charged per parameter),
        along the train model's blur direction. A blur mostly lowers the contrast, which a gain and
        offset per frame also explain with twice the unknowns: the loop tries both and keeps what
        tracks best."""

        train, val = stage.train, stage.val
        if stage.spec.get(self.name) is not None:
            return None
        rows = val.residual.shape[1]
        direction = np.broadcast_to(blur_direction(train.model, val.data.x_mm), val.residual.shape)
        delta, explained_per_frame = per_frame_blur(val.residual, direction * _response_gain(train.model), val.usable)
        explained = float(explained_per_frame.sum())
        sigma2 = val.data.sigma_gray**2
        z = z_beyond_noise(explained, len(delta), sigma2)
        # fitted on the held-out frames, one unknown each: what noise alone would give it is not evidence
        share = share_above_noise(explained - len(delta) * sigma2, train, val)
        spread_px2 = float(np.std(delta)) / train.model.pixel_pitch_mm**2
        return Evidence(self.name, "time (per frame, along ∂S/∂δ)", explained, z, share,
                        f"a change of focus per frame ({spread_px2:.2f} px² rms of blur variance, {rows} row(s)) "
                        f"would {explains(share)}")

    def fit_step(self, setting, state):
        direction = blur_direction(state.model, state.x_mm)  # (K, Rm, n), the smooth model's ∂S/∂δ
        target = state.lit + state.blurred * state.map_factor - state.smooth * state.map_factor
        shaded = direction * state.map_factor
        delta, _ = per_frame_blur(target, shaded, state.weights)
        delta -= np.average(delta)  # the smooth model holds the mean focus
        state.blurred = delta[:, None, None] * direction
        state.found = {**(state.found or {}), "focus_mm2": delta}

    def finish(self, setting, state, model):
        delta = (state.found or {}).get("focus_mm2")
        if delta is None:
            return model
        footprint = model.pixel_pitch_mm**2
        info = {**model.info, FOCUS_INFO: True, "calibration_focus_spread_px2": float(np.std(delta)) / footprint,
                "calibration_focus_range_px2": [float(delta.min()) / footprint, float(delta.max()) / footprint]}
        return model.with_changes(info=info, coeffs=model.coeffs)


def _response_gain(model: FourierModel) -> np.ndarray | float:
    """The flat field's gain per pixel (what multiplies the smooth part in a prediction)."""
    return model.response()[0]


def with_frame_focus(model: FourierModel, x_mm: np.ndarray, frames: np.ndarray, predicted: np.ndarray,
                     usable: np.ndarray) -> np.ndarray:
    """``predicted`` with each frame's own change of focus fitted: how a model calibrated with
    the focus effect sees frames it did not fit (the tracker solves the same term)."""
    direction = np.broadcast_to(blur_direction(model, x_mm) * _response_gain(model), frames.shape)
    delta, _ = per_frame_blur(frames - predicted, direction, usable)
    return predicted + delta[:, None, None] * direction


EFFECT = Focus()
