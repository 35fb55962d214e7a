"""The grating read at another instant than the exposure: a correction of the calibration data."""

from __future__ import annotations

import numpy as np

from graytrack.core.effects import Effect
from graytrack.core.timing import at_exposure, velocity_mm_s
from graytrack.core.evidence import Evidence

MIN_SHARE = 0.2  # velocity must explain this share of the error variance to count as a timing fault
MIN_FRAMES = 10


class ReferenceTiming(Effect):
    name = "reference_timing"
    frame_part = "calibration only"  # core/frame_tables.py: what tracking reads of it
    family = "grating read at another instant than the exposure (latch skew, readout latency)"
    adds = ("the reference moved to mid-exposure: x(t) = ref(t) − v·δ (a correction of the data, kept in "
            "model.json as info.reference_skew_s)")
    fitted = "δ from the regression of the held-out error on velocity"
    order = 2
    data_quality = True

    def probe(self, stage):
        """Tracking error proportional to velocity; the argument is the skew δ (s) that −v·δ fits."""

        val, error_um = stage.val, stage.figures.error_um
        velocity = velocity_mm_s(val.data.t_s, val.data.x_mm)
        usable = np.isfinite(error_um)
        v, e = velocity[usable], error_um[usable]
        if v.size < MIN_FRAMES:
            return None
        spread = float(((v - v.mean()) ** 2).sum())
        if spread <= 1e-12:
            return None
        slope = float(((v - v.mean()) * (e - e.mean())).sum() / spread)  # µm per (mm/s)
        fitted = e.mean() + slope * (v - v.mean())
        remaining = float(((e - fitted) ** 2).sum())
        total = float(((e - e.mean()) ** 2).sum())
        z = abs(slope) / np.sqrt(remaining / (v.size - 2) / spread) if remaining > 0 else np.inf
        share = 1.0 - remaining / total if total > 0 else 0.0
        if share <= MIN_SHARE:
            return None
        skew_s = -slope * 1e-3  # e = −v·δ with e in µm, v in mm/s
        return Evidence(self.name, "velocity", share, float(z), share,
                        f"the tracking error follows velocity: the grating reads {skew_s * 1e3:+.3f} ms from "
                        f"mid-exposure (−v·δ explains {100 * share:.0f}% of the error variance)", skew_s)

    def grow(self, spec, argument):
        return None if argument is None else spec.set(self.name, spec.get(self.name, 0.0) + float(argument))

    def prepare_data(self, setting, data):
        return data.with_reference(at_exposure(data.t_s, data.x_mm, setting)) if setting else data

    def finish(self, setting, state, model):
        return model.with_changes(coeffs=model.coeffs, info={**model.info, "reference_skew_s": setting})


EFFECT = ReferenceTiming()
