"""The lens's stretch followed in time and taken out of each frame before it is solved.

A magnification that drifts by m stretches the image across the pixels, ``m·F'_u·(s_u − s_c)``
in each frame (core/stretch.py), besides the slide ``m·(s_c − s_axis)`` the trim takes out
against the grating (core/trim_follow.py). Left in the frame, the stretch is a misfit the solve
does not know: its χ² rises, and the tracker's light field and focus term are switched on to
explain it. They do, by trading their shapes against the position: a 16-row strip whose
magnification drifted 0.15 % over 10 s had its last ~30 frames placed by the light field at bounds
of 2.6 µm, 5-10 µm off (the run 1.8-2.1× its bound with the trim, 1.04× without those frames).

:class:`StretchFollow` keeps the stretch the frames show, as the magnification watch measures it
(less the model's own, ``stretch_profile``), on an exponentially weighted line in time (the trim's
:class:`~graytrack.core.trim_follow.Follower`, in ppm): once its value now is significant, each
frame is solved with that stretch taken out of it (the model's slope at the predicted position
times each sample's place along the line, times the light's gain: first order, ≪ 1 % of the
correction off for a prediction tens of µm off). Each frame's own stretch is then measured on
what is left and added back, so the line follows the total. What a frame had taken out is kept,
in order, for the trim's magnification watch (core/watches/scale.py): with a trim in force it is
a stretch followed, not a model gone stale.
"""

from __future__ import annotations

import collections
import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from graytrack.core.compression import stream_bound_factor
from graytrack.core.solvers import GeneralBatch, TrigPolyBatch
from graytrack.core.stretch import frame_stretch
from graytrack.core.trim_follow import Follower

MEMORY = 20.0  # frames: the line's time constant (a 16-row frame knows its stretch to ~450 ppm: ~150 ppm now)
# the line's value now is taken out once this many of its σ from zero (the trim's own follower: 3). It is tested on
# every frame: at 3σ a 500-frame run of noise alone took a stretch out on 13 of 200 seeded runs, at 4 on none; and
# a model's own misfit reads as a stretch the same way (the seed model under clipping it lacks reached 3.0-3.6σ on
# steady runs, 4000 ppm taken out of 20 frames, which tried the focus term on them). A lens's ramp or cycle on a
# 16-row strip is still followed as at 3 (bench/magnification_drift.py: the same ratios under --trim)
APPLY_Z = 4.0
KEPT = 8192  # frames whose taken-out stretch waits for the watch (a batch chunk's worth, and more)


@dataclass(frozen=True)
class Taken:
    """One frame's record, ppm: the stretch taken out of it (0 while the line is not significant),
    the line's value at the frame whether taken out or not and its σ (NaN, inf: no line yet), and
    the stretch the frame showed in all (taken out + measured on what was left; NaN: not measured)."""

    ppm: float = 0.0
    followed_ppm: float = math.nan
    sigma_ppm: float = math.inf
    total_ppm: float = math.nan


class StretchFollow:
    """``corrected(...)`` before a frame's solve, ``observe(...)`` after it; :meth:`taken` for the watch."""

    def __init__(self, profile=None, memory: float = MEMORY, noise_factor: float = 1.0) -> None:
        self.profile = profile  # the model's own stretch along the stroke (a StretchProfile), taken out
        # a frame's stretch error over its white-noise σ: a lossy stream's (core/compression.py) quantisation lies
        # along F'·s as along x's F'; left white, the line's own scatter estimate over a few tens of frames is
        # the only widening, and a steady `lab` run at quality 75 (its stretches 3.3 σ in rms) had 17 frames
        # solved with a stretch taken out at 4.4 of the line's σ
        self.noise_factor = noise_factor
        self.follower = Follower(memory=memory, apply_z=APPLY_Z)
        self._centred_mm: np.ndarray | None = None  # each sample's place along the line (the tracker's model)
        self.current = Taken()  # the frame being solved
        self.corrected_frames = 0  # frames solved with a stretch taken out
        self._log: collections.deque[Taken] = collections.deque(maxlen=KEPT)
        self._measured: tuple[float, float] | None = None

    @classmethod
    def for_model(cls, model) -> "StretchFollow":
        from graytrack.core.watches.magnification import StretchProfile  # (the watch's own record of it)

        info = getattr(model, "info", None) or {}
        doc = info.get("stretch_profile")
        return cls(StretchProfile.from_dict(doc) if isinstance(doc, dict) else None,
                   noise_factor=stream_bound_factor(info))

    def _centred(self, model) -> np.ndarray:
        """Each sample's target offset about the line's centre, mm: a fixed centre (a centre moving with
        each frame's weights would move the slide with it)."""
        if self._centred_mm is None:
            offsets = model.target_offset().reshape(-1)
            seen = np.ones_like(offsets) if model.pixel_weight is None else \
                (np.asarray(model.pixel_weight, dtype=np.float64).reshape(-1) > 0).astype(np.float64)
            self._centred_mm = offsets - float(seen @ offsets) / max(float(seen.sum()), 1.0)
        return self._centred_mm

    def corrected(self, tracker, batch: GeneralBatch | TrigPolyBatch, k: int, x_guess: float,
                  gain: float) -> tuple[GeneralBatch | TrigPolyBatch, int]:
        """Batch frame ``k`` with the followed stretch taken out at ``x_guess`` (a one-frame batch), or
        the batch itself while the line is not significant or the frame has no predicted place."""
        self.follower.tick()
        following = self.follower.now()  # (the follower's units: ppm here)
        line = self.follower.estimate()
        self._measured = None
        applied = following.correction_um if math.isfinite(x_guess) else 0.0
        self.current = Taken(applied, *(line[:2] if line is not None else (math.nan, math.inf)))
        if not applied:
            return batch, k
        m = applied * 1e-6
        self.corrected_frames += 1
        _, slopes = tracker.evaluator.evaluate(np.array([x_guess]))
        frame = batch.frames[k] - (gain * m) * slopes[0] * self._centred(tracker.model)
        weights = batch.weights(k)
        if tracker.fast_path:
            return TrigPolyBatch(tracker.tables, frame[None], weights[None], evaluator=tracker.evaluator), 0
        return GeneralBatch.one(tracker.evaluator, frame[None], weights[None]), 0

    def observe(self, tracker, batch: GeneralBatch | TrigPolyBatch, k: int, solution, placed: bool) -> None:
        """The frame as solved (on the batch :meth:`corrected` gave): its stretch measured on what was
        left, the total fed to the line."""
        total = math.nan
        if placed and math.isfinite(solution.x_mm):
            m, sigma = frame_stretch(tracker, batch, k, solution)
            if math.isfinite(m) and 0 < sigma < math.inf:
                total = self.current.ppm + m * 1e6
                self._measured = (total * 1e-6, sigma)
                own = self.profile.at_ppm(solution.x_mm) if self.profile is not None else 0.0
                self.follower.add(total - own, (self.noise_factor * sigma * 1e6) ** 2)
        self.current = dataclasses.replace(self.current, total_ppm=total)
        self._log.append(self.current)

    def measured(self) -> tuple[float, float]:
        """The last frame's stretch in all (m, σ: the watch's ``stretch``), dimensionless."""
        return self._measured if self._measured is not None else (math.nan, math.inf)

    def status(self) -> dict:
        """What is followed, for a status page: the line's value now and its σ (ppm; None before it has
        evidence), whether the frames are solved with it taken out, and how many were."""
        line = self.follower.estimate()
        return {"followed_ppm": None if line is None else round(line[0], 1),
                "sigma_ppm": None if line is None else round(line[1], 1),
                "taken_out": bool(self.current.ppm), "frames_corrected": self.corrected_frames}

    def taken(self) -> Taken:
        """The oldest frame's record not yet read (frames are read in the order they were solved)."""
        return self._log.popleft() if self._log else Taken()


def followed_stretch(follow: StretchFollow):
    """The frame just observed's stretch in all, for the watches (read later, in a batch: kept now)."""
    measured = follow.measured()
    return lambda: measured


def stretch_follow(watches) -> StretchFollow | None:
    """The follower an owner's watch carries (the trim's scale watch: ``ScaleWatch(..., stretch=)``), if any."""
    return next((watch.stretch_follow for watch in watches if getattr(watch, "stretch_follow", None) is not None),
                None)
