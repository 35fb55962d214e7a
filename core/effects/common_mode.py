"""A gain and an offset per frame: flicker, auto-exposure, drift of the light."""

from __future__ import annotations

import numpy as np

from graytrack.core.effects import Effect
from graytrack.core.regression import weighted_affine
from graytrack.core.evidence import Evidence, explains, share_above_noise, z_beyond_noise


class CommonMode(Effect):
    name = "common_mode"
    frame_part = "per-frame unknowns"  # core/frame_tables.py: what tracking reads of it
    family = "light or exposure changing from frame to frame (flicker, auto-exposure, drift)"
    adds = "a gain and an offset per frame"
    fitted = "alternating least squares in calibration; solved with x in tracking"
    order = 31
    bilinear = True

    def probe(self, stage):
        """A gain and offset per frame, fitted on the held-out frames themselves (charged per parameter)."""

        train, val = stage.train, stage.val
        if train.model.common_mode:
            return None
        r = val.residual
        gain, offset = weighted_affine(r, val.predicted, val.usable, axis=(1, 2))
        corrected = (r - (gain[:, None, None] * val.predicted + offset[:, None, None])) * val.usable
        explained = float((r**2).sum() - (corrected**2).sum())
        noise_removes = 2 * len(gain) * val.data.sigma_gray**2  # fitted on these very frames: noise gives some
        z = z_beyond_noise(explained, 2 * len(gain), val.data.sigma_gray**2)
        share = share_above_noise(explained - noise_removes, train, val)
        # Smooth-in-stroke gain belongs to the stroke probe; only what varies from frame to frame counts here.
        jitter = np.diff(gain[np.argsort(val.data.x_mm)])
        frame_to_frame = float(np.std(jitter) / np.sqrt(2)) * 100
        return Evidence(self.name, "time (per frame)", explained, z, share,
                        f"a gain per frame ({frame_to_frame:.2f}% rms from frame to frame) "
                        f"and offset {explains(share)}")

    def model_fields(self, setting):
        return {"common_mode": True}

    def fit_step(self, setting, state):
        gain, offset = weighted_affine(state.raw, state.pixel_gain * state.shaded + state.pixel_offset, state.weights,
                                       axis=(1, 2))
        state.frame_offset = offset - offset.mean()
        state.frame_gain = gain / gain.mean()


EFFECT = CommonMode()
