"""A gain and an offset per pixel: PRNU, DSNU, dust on the sensor."""

from __future__ import annotations

import numpy as np

from graytrack.core.effects import Effect
from graytrack.core.regression import weighted_affine
from graytrack.core.evidence import Evidence, explains, share_above_noise


def rough_part(values: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """``values`` ``(R, n)`` minus their least-squares fit by the pixel polynomials ``(n, P+1)``:
    the flat field keeps only what the smooth model cannot hold, so the split is unique."""
    coef, *_ = np.linalg.lstsq(basis, values.T, rcond=None)
    return values - (basis @ coef).T


class FlatField(Effect):
    name = "flat_field"
    frame_part = "response"  # core/frame_tables.py: what tracking reads of it
    family = "pixel-to-pixel response (PRNU gain, DSNU offset, dust on the sensor)"
    adds = "a gain and an offset per pixel (the part the pixel polynomials cannot hold)"
    fitted = "alternating least squares with the smooth part"
    order = 30
    bilinear = True

    def probe(self, stage):
        """A gain and offset per pixel, fitted on training frames, applied to held-out ones."""

        train, val = stage.train, stage.val
        slope, intercept = weighted_affine(train.residual, train.predicted, train.usable, axis=(0,))
        r_v = val.residual
        corrected = r_v - (slope * val.predicted + intercept) * val.usable
        explained = float((r_v**2).sum() - (corrected**2).sum())
        sigma2 = val.data.sigma_gray**2
        z = explained / sigma2 / np.sqrt(2.0 * 2 * slope.size)
        spread = float(np.std(slope)) * 100
        share = share_above_noise(explained, train, val)  # fitted on training frames: cross-validated
        return Evidence(self.name, "pixel index (pixel to pixel)", explained, z, share,
                        f"a gain ({spread:.2f}% rms) and offset per pixel {explains(share)}")

    def fit_step(self, setting, state):
        gain, offset = weighted_affine(state.per_frame, state.shaded, state.weights, axis=(0,))
        basis = state.model.pixel_basis()
        state.pixel_gain = 1.0 + rough_part(gain - 1.0, basis)
        state.pixel_offset = rough_part(offset, basis)

    def finish(self, setting, state, model):
        return model.with_changes(pixel_gain=state.pixel_gain, pixel_offset=state.pixel_offset, coeffs=model.coeffs)


EFFECT = FlatField()
