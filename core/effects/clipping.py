"""A sensor clipped at its floor or ceiling: clipped samples carry no position."""

from __future__ import annotations

import numpy as np

from graytrack.core.effects import Effect
from graytrack.core.evidence import Evidence

MIN_SHARE = 0.002  # a continuous signal plus noise almost never repeats its extreme value this often


class Clipping(Effect):
    name = "clipping"
    frame_part = "clip"  # core/frame_tables.py: what tracking reads of it
    family = "sensor saturation or a black clip"
    adds = "the clip limits: clipped samples carry no position"
    fitted = "clipped samples get zero weight in calibration and zero slope in tracking"
    order = 3
    data_quality = True

    def probe(self, stage):
        """Samples piled up at the top or bottom of the gray range (masked pixels left out)."""

        train = stage.train
        if train.model.clip_gray is not None:
            return None
        frames = train.data.frames[:, np.asarray(train.data.weights).max(axis=0) > 0]
        top, bottom = float(frames.max()), float(frames.min())
        at_top, at_bottom = float((frames >= top).mean()), float((frames <= bottom).mean())
        if max(at_top, at_bottom) < MIN_SHARE:
            return None
        limits = (float(bottom if at_bottom >= MIN_SHARE else -np.inf), float(top if at_top >= MIN_SHARE else np.inf))
        share = max(at_top, at_bottom)
        return Evidence(self.name, "gray level", 0.0, 1e3 * share, share,
                        f"{100 * at_top:.1f}% of samples sit at the ceiling {top:g} and {100 * at_bottom:.1f}% at "
                        f"the floor {bottom:g}: the sensor clips there", limits)

    def grow(self, spec, argument):
        return None if spec.get(self.name) is not None or argument is None else spec.set(self.name, tuple(argument))

    def model_fields(self, setting):
        return {"clip_gray": tuple(setting)}

    def prepare_data(self, setting, data):
        lo, hi = setting
        return data.with_weights(data.weights * ((data.frames > lo) & (data.frames < hi)))


EFFECT = Clipping()
