"""The ``magnification`` watch: the image stretching across the pixels since calibration.

A lens warming up changes its magnification by parts per thousand; with the optical axis off the
ROI the image then also slides, tens of µm while the stage stands, which the tracker takes for a
position and no image can tell from one. The stretch that comes with it can be told: each frame's
residual has the shape ``m·F'_u·(s_u − s_c)`` (core/stretch.py); one frame of a 16-row strip knows m
to ~400 ppm, an exponentially weighted mean over the last :data:`MEMORY` frames to ~60. The watch
blames ``magnification`` while that mean is beyond :data:`Z_ON` of its standard error (the frames'
noise, scaled up by their own scatter, and :data:`STRUCTURE_PPM`: a model's own error along the
stroke reads as up to ~150 ppm over 50 frames of a steady strip), until it falls below
:data:`Z_OFF`. It needs no grating: a rig tracked without one is named, not silently off.

A magnification is the same m whatever part of the print is in view; a print that changed (a
harmonic grown by 2 %) also leaves some of that shape in each frame, but one that turns with the
print's phase under the line (it read as a steady 300 ppm on 145 of 300 frames). So the same frames
are also fitted as that mean, a drift in time and the first two harmonics of the phase, and a mean
whose turning part is significant and larger than itself is not called a magnification (the χ² watch
names the print's change). Without the drift term a lens's stretch growing while the stage moved
was taken up by the harmonics: a 16-row temperature cycle (1500 ppm) read 1000 ppm at 15σ, unflagged
as turning, on half its frames.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from graytrack.core.period_rival import repeats
from graytrack.core.stretch import chunk_stretches
from graytrack.core.stretch import warm as stretch_warm
from graytrack.core.place_spread import PlaceSpread, model_share
from graytrack.core.watches import _kernels

MEMORY = 50  # frames: the mean's time constant
MIN_FRAMES = 20  # frames (decayed count) before it says anything
Z_ON, Z_OFF = 4.0, 2.5
STRUCTURE_PPM = 40.0  # what a calibrated model's own structure reads as a stretch, in a mean of MEMORY frames
PRIOR_PPM = 20000.0  # the prior's σ on each phase harmonic: keeps the turning fit defined while the stage stands
PROFILE_BINS = 16  # stretches of the stroke the calibration's own stretch is kept for
FOLD_POINTS = 64  # places of one period a profile folded onto it is kept at (StretchProfile.folded)
NOISE_SHARE = 0.3  # of a stretch mean's noise kept as the model's own stretch there (0: a clean paper run flagged 4 %)
COVERAGE = 0.1  # each harmonic's share of the frames' weight, beside a level and a drift, before a turning is told
TURNING_CHI2 = 36.0  # the turning part (4 harmonic terms) is significant beyond this χ² (p ≈ 3e-7)
LENS_PPM = 10000.0  # a stretch beyond 1 % is no lens's (tens of ppm per kelvin): the print or the model changed
CHANGE_PRIOR_PPM = 2000.0  # σ of a lens's change since calibration before any frame tells (0.2 %: tens of kelvin)


class MagnificationWatch:
    """``step(placed, x_mm, stretch) -> "magnification" | None`` from each placed frame's stretch."""

    family = "magnification"
    reads = ("placed", "x_mm", "stretch")

    def __init__(self, period_mm: float, profile: "StretchProfile | None" = None, record: bool = False,
                 place_share: float = 0.0) -> None:
        """``place_share``: of a frame's stretch variance, the model's own at a place (core/place_spread.py)."""
        self.period_mm = period_mm
        self.profile = profile  # the model's own stretch along the stroke, from its calibration frames
        self.allowance_ppm = max(STRUCTURE_PPM, profile.residual_ppm if profile is not None else 0.0)
        self.record: list[tuple[float, float, float]] | None = [] if record else None  # (x, m, σ) per frame
        # b: 1, the frame's age −a/MEMORY (a drift in time) and the phase's harmonics; one frame on,
        # every age term moves 1/MEMORY further back (core/watches/_kernels.py steps them, compiled)
        self._normal = np.zeros((6, 6))  # Σ dᵃ·w·b·bᵀ (a: a frame's age)
        self._noise = np.zeros((6, 6))  # Σ d²ᵃ·w·b·bᵀ: an estimate's noise is N⁻¹·this·N⁻¹
        self._right = np.zeros(6)  # Σ dᵃ·w·b·m
        # Σ dᵃ·w·m², Σ dᵃ, the mean (ppm) and its σ, the variance of the stretch a trim accounts for
        # (ppm²), flagged
        self._scalars = np.array([0.0, 0.0, 0.0, math.inf, 0.0, 0.0])
        self._params = np.array([math.exp(-1.0 / MEMORY), period_mm, -(1.0 / MEMORY), MIN_FRAMES,
                                 self.allowance_ppm ** 2, Z_ON, Z_OFF])
        self._prior = np.diag([0.0, 0.0] + [PRIOR_PPM ** -2] * 4)
        self.turning_ppm = 0.0
        # the model's own stretch at the places the mean was taken (a stage at rest never averages it):
        # added to the mean's variance, with the accounted stretch's, in _scalars[4] (core/place_spread.py)
        self.place = PlaceSpread(math.exp(-1.0 / MEMORY), place_share)
        self._accounted_var = 0.0  # ppm²: the stretch a trim accounts for

    @property
    def flagged(self) -> bool:
        return self._scalars[5] != 0.0

    @property
    def mean_ppm(self) -> float:
        return float(self._scalars[2])

    @property
    def sigma_ppm(self) -> float:
        return float(self._scalars[3])

    @classmethod
    def for_model(cls, model, unplaced: bool = False) -> "MagnificationWatch":
        """Less what the model read on its own calibration (``stretch_profile`` in its info, when it has
        one); its compiled loops ready now, at model install, not on a live frame. ``unplaced``: no
        grating places the frames, so a model that repeats once a period reads it folded onto one."""
        _warm()
        doc = (getattr(model, "info", None) or {}).get("stretch_profile")
        profile = StretchProfile.from_dict(doc) if isinstance(doc, dict) else None
        if profile is not None and unplaced and repeats(model):
            profile = profile.folded(model.period_mm)
        return cls(model.period_mm, profile, place_share=model_share(model))

    def observe(self, sign) -> str | None:
        return self.step(sign.placed, sign.x_mm, sign.stretch)

    def step(self, placed: bool, x_mm: float, stretch, accounted_ppm: float = 0.0,
             accounted_sigma_ppm: float = 0.0) -> str | None:
        """``accounted_ppm`` (± its σ): the stretch a trim in force takes out of the positions (a grown
        print's, core/watches/scale.py), judged as the calibration's: what is left is the lens's."""
        self._accounted_var = accounted_sigma_ppm * accounted_sigma_ppm
        self._scalars[4] = self._accounted_var
        if placed and stretch is not None and math.isfinite(x_mm):
            m, sigma = stretch()
            if math.isfinite(m) and 0 < sigma < math.inf:
                if self.record is not None:
                    self.record.append((x_mm, m * 1e6, sigma * 1e6))
                own = self.profile.at_ppm(x_mm) if self.profile is not None else 0.0
                sigma_ppm = sigma * 1e6
                self._scalars[4] += self.place.add(x_mm, 1.0 / (sigma_ppm * sigma_ppm))
                self._add(x_mm, m * 1e6 - own - accounted_ppm, sigma_ppm)
        if not self.flagged:
            return None
        # a print harmonic grown 2 % read as a steady 17000-25000 ppm while the stage saw less than a period
        # (the image's own stretch: what a trim accounts for is a lens's slide read as a scale)
        return self.family if abs(self.mean_ppm + accounted_ppm) <= LENS_PPM else "geometry"

    @property
    def rms_ppm(self) -> float:
        """The rms stretch since calibration the frames allow now, √(mean² + σ²): the mean over the
        memory and its σ as the decision takes them, from the first frame on (shrunk by
        :data:`CHANGE_PRIOR_PPM`, which is all there is before one): what a slide may be made of
        while no grating vouches (core/slide.py)."""
        mean, variance = self._level(CHANGE_PRIOR_PPM ** -2)
        return math.sqrt(mean * mean + variance)

    def so_far(self) -> tuple[float, float]:
        """The stretch mean (ppm) and its σ to weigh causes by (core/watches/scale.py): the decision's once
        :data:`MIN_FRAMES` are in; before, the same level over the frames seen so far (two at least),
        its σ from their own noise and scatter as the decision takes them (inf: none yet). The frames'
        flag waits for its frames (a 4σ test on every frame); what drifted a line already found off the
        grating needs only the frames' evidence: a lens's first 15 flagged frames named ``scale`` read a
        line scale of 3500-7000 ppm (± 1600-540) beside a stretch near none, which no grown print gives."""
        if math.isfinite(self.sigma_ppm) or self._scalars[1] < 2.0:
            return self.mean_ppm, self.sigma_ppm
        mean, variance = self._level(0.0)
        return mean, math.sqrt(variance)

    def _level(self, prior: float) -> tuple[float, float]:
        """The level of the stretches over the memory (ppm) and its variance (ppm²), shrunk by a
        ``prior`` precision (1/ppm²; 0: none) toward no change, as the decision weighs it: the frames'
        noise scaled by their scatter, the model's own allowance and what a trim accounts for."""
        total = self._normal[0, 0] + prior
        mean = self._right[0] / total
        squares, frames, accounted_var = self._scalars[0], self._scalars[1], self._accounted_var
        scatter = max((squares - mean * self._right[0]) / (frames - 1.0), 1.0) if frames > 2 else 1.0
        variance = (self._noise[0, 0] * scatter + prior) / (total * total) + self.allowance_ppm ** 2 + accounted_var
        return mean, variance

    def step_many(self, columns, n: int) -> list[str | None] | None:
        """:meth:`step` of ``n`` frames at once: their stretches by one compiled call when batch tracking
        left them (core/stretch.py), the running sums by a compiled loop that hands a frame whose mean
        is significant to :meth:`_turning` (numpy's), as :meth:`step` does. None without numba."""
        if not _kernels.COMPILED:
            return None
        x = columns.array("x_mm", np.float64)
        m, sigma = chunk_stretches(columns["stretch"], asked_stretches(columns))
        use = np.isfinite(m) & (0 < sigma) & (sigma < math.inf)
        if self.record is not None:
            self.record.extend(zip(x[use].tolist(), (m[use] * 1e6).tolist(), (sigma[use] * 1e6).tolist()))
        own = self.profile.at_ppm(x) if self.profile is not None else 0.0
        m_ppm = np.where(use, m * 1e6 - own, 0.0)  # as step: no trim accounts for any of it here
        sigma_ppm = np.where(use, sigma * 1e6, 1.0)
        self._scalars[4] = self._accounted_var = 0.0
        out = np.zeros(n, dtype=np.bool_)
        beyond = np.zeros(n, dtype=np.bool_)  # flagged with a mean no lens makes (as step: LENS_PPM)
        start = 0
        while (start := self._run(x, m_ppm, sigma_ppm, use, start, out)) < n:
            self._judge(self._scalars[2])  # a significant mean: does it turn with the phase?
            out[start] = self.flagged
            beyond[start] = abs(self.mean_ppm) > LENS_PPM
            start += 1
        if not out.any():
            return [None] * n
        return [("geometry" if far else self.family) if flagged else None
                for flagged, far in zip(out.tolist(), beyond.tolist())]

    def _run(self, x, m_ppm, sigma_ppm, use, start: int, out) -> int:
        place = self.place
        return _kernels._magnification_run(self._normal, self._noise, self._right, self._scalars, x, m_ppm,
                                           sigma_ppm, use, start, self._params, out, place.roots, place.total,
                                           place.params)

    def _add(self, x_mm: float, m_ppm: float, sigma_ppm: float) -> None:
        if _kernels._magnification_add(self._normal, self._noise, self._right, self._scalars, float(x_mm),
                                       float(m_ppm), float(sigma_ppm), self._params):
            self._judge(self._scalars[2])

    def _judge(self, mean: float) -> None:
        """The flag of a frame whose mean is significant: up unless the stretch turns with the phase."""
        self._scalars[5] = 0.0 if self._turning(float(mean)) else 1.0

    def _turning(self, mean: float) -> bool:
        """Whether the frames' stretch turns with the print's phase, significantly and by more than
        its mean: a print's change, not a lens's."""
        normal = self._normal
        # the phases the window saw, beside a level and a drift: a stage that stood or turned round saw
        # too few for the harmonics to be told from a stretch changing in time (they took 2000-4000 ppm)
        held = normal[2:, 2:] - normal[2:, :2] @ np.linalg.solve(normal[:2, :2], normal[:2, 2:])
        if np.linalg.eigvalsh(held)[0] < COVERAGE * normal[0, 0]:
            return False
        inverse = np.linalg.inv(normal + self._prior)
        coef = inverse @ self._right
        covariance = inverse @ self._noise @ inverse
        turning = coef[2:]  # beside a drift in time: a stretch that grows while the stage moves is no turning
        chi2 = float(turning @ np.linalg.solve(covariance[2:, 2:], turning))
        self.turning_ppm = math.sqrt(float(turning @ turning) / 2.0)
        return chi2 > TURNING_CHI2 and self.turning_ppm > abs(mean)


@dataclass(frozen=True)
class StretchProfile:
    """What a calibrated model reads as a stretch on its own calibration frames, stretch by stretch
    of the stroke: its own error (a scratch it cannot follow, a pattern it lacks) is fixed in
    position and shows again at the same places in every run, so it is taken out of a run's
    estimates. ``residual_ppm``: what is left between the stretches beyond their noise (and the
    profile's own noise), the watch's allowance."""

    centers_mm: tuple[float, ...]
    values_ppm: tuple[float, ...]
    residual_ppm: float
    fold_mm: float = 0.0  # > 0: read at a place known only up to whole ones of these (:meth:`folded`)

    def at_ppm(self, x_mm: float | np.ndarray) -> float | np.ndarray:
        """The model's own stretch at ``x_mm`` (one position, or an array of them), ppm."""
        if self.fold_mm > 0.0:
            x_mm = self.centers_mm[0] + np.mod(np.asarray(x_mm, dtype=np.float64) - self.centers_mm[0], self.fold_mm)
        if np.ndim(x_mm):
            return np.interp(x_mm, *self._nodes)
        return float(np.interp(x_mm, *self._nodes))

    @functools.cached_property
    def _nodes(self) -> tuple[np.ndarray, np.ndarray]:
        """The centres and values as arrays, made once: every frame reads the profile."""
        return np.array(self.centers_mm), np.array(self.values_ppm)

    def folded(self, period_mm: float) -> "StretchProfile":
        """The profile for frames placed only up to whole periods (a model that repeats, tracked without
        a grating: core/stroke_place.py): at each place of one period, the mean of what it holds at the
        places whole periods on, their largest spread added to the allowance. Read at the place given, a
        16-row JPEG strip's own stretch (±100-500 ppm along the stroke) was read a period away and a
        steady run flagged `magnification` on 14 % of its frames."""
        first, last = self.centers_mm[0], self.centers_mm[-1]
        if not period_mm > 0.0:
            return self
        grid = first + np.linspace(0.0, period_mm, FOLD_POINTS, endpoint=False)
        places = grid[None, :] + period_mm * np.arange(int((last - first) // period_mm) + 1)[:, None]
        inside = (places <= last) | (np.arange(places.shape[0]) == 0)[:, None]  # (the first always counts)
        values = np.where(inside, np.interp(places, *self._nodes), np.nan)
        mean = np.nanmean(values, axis=0)
        spread = float(np.sqrt(np.nanmean((values - mean) ** 2, axis=0)).max())  # where the places disagree most
        return StretchProfile(tuple(grid.tolist()), tuple(mean.tolist()), math.hypot(self.residual_ppm, spread),
                              period_mm)

    def as_dict(self) -> dict:
        return {"centers_mm": [round(v, 6) for v in self.centers_mm],
                "values_ppm": [round(v, 2) for v in self.values_ppm], "residual_ppm": round(self.residual_ppm, 2)}

    @classmethod
    def from_dict(cls, doc: dict) -> "StretchProfile":
        return cls(tuple(map(float, doc["centers_mm"])), tuple(map(float, doc["values_ppm"])),
                   float(doc["residual_ppm"]))

    @classmethod
    def measured(cls, record: list[tuple[float, float, float]], bins: int = PROFILE_BINS) -> "StretchProfile | None":
        """From a calibration's frames (x, m, σ): weighted means in ``bins`` equal stretches of the
        positions seen, shrunk towards zero as their noise bids (positive-part James–Stein)."""
        if len(record) < 4 * bins:
            return None
        x, m, sigma = (np.array(column) for column in zip(*record))
        edges = np.linspace(x.min(), x.max() + 1e-12, bins + 1)
        which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
        w = sigma ** -2
        total = np.bincount(which, w, bins)
        kept = np.flatnonzero(total > 0)
        means = np.bincount(which, w * m, bins)[kept] / total[kept]
        centers = np.bincount(which, w * x, bins)[kept] / total[kept]
        noise2 = 1.0 / total[kept]
        spread2 = float(np.mean(means * means))
        shrink = max(1.0 - float(np.mean(noise2)) / max(spread2, 1e-300), 0.0)
        # what is left at a place: a stretch's mean is known to its noise whether it is kept or shrunk
        # away (a model's own stretch of 500 ppm over two stretches of a one-row stroke hides in 190 ppm
        # of noise per stretch and showed in a clean run as a magnification), plus the part shrunk away
        beyond = math.sqrt(max(spread2 - float(np.mean(noise2)), 0.0))  # the structure beyond the means' noise
        left = NOISE_SHARE * math.sqrt(float(np.mean(noise2))) + (1.0 - shrink) * beyond
        return cls(tuple(centers.tolist()), tuple((means * shrink).tolist()), left)


def asked_stretches(columns) -> np.ndarray:
    """The frames of a chunk whose stretch :meth:`MagnificationWatch.step` reads: placed, at a finite
    position, with a stretch to compute."""
    given = np.fromiter((entry is not None for entry in columns["stretch"]), dtype=bool, count=len(columns["stretch"]))
    return np.flatnonzero(columns.array("placed", bool) & np.isfinite(columns.array("x_mm", np.float64)) & given)


def make(tracker) -> MagnificationWatch:
    """Every tracker's: the stretch is in the frames, with a grating or without (a trimmed run's scale
    watch carries its own, judged against the trim: core/watches/scale.py). Its compiled loops are
    made ready here, at model install, not on a live frame."""
    stretch_warm(tracker)
    return MagnificationWatch.for_model(tracker.model)


@functools.cache
def _warm() -> None:
    """Compile (or load from numba's cache) the running sums' loops, once a process."""
    watch = MagnificationWatch.__new__(MagnificationWatch)
    watch._normal, watch._noise, watch._right = np.zeros((6, 6)), np.zeros((6, 6)), np.zeros(6)
    watch._scalars = np.array([0.0, 0.0, 0.0, math.inf, 0.0, 0.0])
    watch._params = np.array([1.0, 1.0, 0.0, math.inf, 0.0, Z_ON, Z_OFF])  # never enough frames to judge
    watch.place = PlaceSpread(1.0, 0.0)
    watch.place.add(0.0, 1.0)
    watch._add(0.0, 0.0, 1.0)
    one = np.zeros(1)
    watch._run(one, one, np.ones(1), np.ones(1, dtype=np.bool_), 0, np.zeros(1, dtype=np.bool_))
