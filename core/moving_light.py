"""A light feature of fixed shape that moves across the field: learned when it comes, followed while it moves.

A cable's shadow, a hand, a lamp's spot: a smooth multiplicative loss of light h(p − c) fixed to
neither the camera nor the print, crossing the field. On a line shorter than a period no field of
a frame's own separates from x (docs/robustness.md: a Legendre field that describes the shadow
costs 30–50× the bound); what does is the shape holding still while it moves. So the shape is
learned from evidence, and each frame solves only where it is (c, in pixels) jointly with x:

    y_p ≈ G · v_p(x) · (1 − h(p − c)) + O

(G, O: the light the frames had before the episode). The shape starts, when a frame the uniform
light does not explain comes, as the loss frame / model at the grating's position, smoothed (the
edge is soft); every frame the feature explains then adds its own loss at its place (again at the
grating's position), so the shape is known where the feature has been seen, and grows as it slides
into view (samples that fall on a part not seen yet carry no weight in that frame's solve). Its
depth is not solved apart: with a shape learned as it goes, depth and shape scale drifted together
(a depth of 5.7 by mid-band), and the shape already carries it.

Only with the grating read: a shape learned at the frames' own x carries each frame's error into
the next (measured on the paper rig: 2.5–43× the bound, 1.8–25 % of the frames 4+ bounds off).

The bound is the joint Fisher information's (x with c profiled out), each sample's variance widened
by the learned shape's own (its precision summed over the frames and rows that built it). The
answer is taken only when it explains the frame (χ² within the single-frame limit of the
calibration's level), the bound is sane, the feature is seen in the frame beyond its noise and has
been seen to move (:data:`MOVED_PX`, :data:`SPEED_PX`); otherwise the uniform answer stands, flagged
as before. The episode ends when the feature stops explaining frames (it has left the field).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from graytrack.core.solvers import FrameSolution

SMOOTH_MM = 0.15  # Gaussian σ of the smoothing of each frame's ratio (a shadow's penumbra is ~1 mm)
EXTENT = 7  # the shape's grid spans this many fields (the feature slides in from either side and out across)
CLEAR_SHARE = 0.2  # a feature's first frame must leave this share of the line's far end unshadowed
SEEN_SIGMAS = 5.0  # the feature seen in a frame: its loss beyond this many of its own noise
MISSES = 3  # frames in a row the feature does not explain before the episode ends
JUMP_PX = 5.0  # the feature's place beyond this from where its motion carries it: not the feature followed
MOVED_PX = 2.0  # the feature's answer is taken once it has moved this far, at SPEED_PX a frame or more on
SPEED_PX = 1.0  # average: a light shape that holds still (a lamp's vignetting: its place wandered ±1.6 px, then
# drifted past 2 px after 30 frames) or a change the shape merely mimics is not one that moves
SANE_BOUND = 10.0  # a joint bound beyond this many of the uniform light's: the place and x no longer separate
ITERATIONS = 6
LIGHT_LAG = 5  # frames: the light the episode holds is the one this many frames before it started (a
# feature's edge is felt a few frames before a frame asks, and a light solved on those frames had
# traded against it: a gain 3 % low placed a shadow's frames 5-10 bounds off), averaged over as many
# frames before those as LIGHT_FRAMES (one frame's solved gain is ±0.5 %: 1.006 held placed 5 frames 4-7 bounds off)
LIGHT_FRAMES = 20


@dataclass
class Follow:
    """The joint answer on one frame."""

    x_mm: float
    information: float
    chi2: float
    cost: float
    centre: float
    visible: float  # the feature's loss in view, in units of its noise


class MovingLight:
    """The state of one episode (or none): the learned shape on a grid of columns, where it is, how it moves."""

    def __init__(self, n_rows: int, n_pixels: int, pixel_pitch_mm: float) -> None:
        self.n_rows, self.n_pixels = n_rows, n_pixels
        radius = SMOOTH_MM / pixel_pitch_mm
        half = max(int(math.ceil(3 * radius)), 1)
        kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / max(radius, 1e-9)) ** 2)
        self.kernel = kernel / kernel.sum()
        self.offset = (EXTENT // 2) * n_pixels  # grid index of column 0 when the feature is at c = 0
        self.columns = np.arange(n_pixels, dtype=np.float64)
        # the last frames' (gain, offset), before an episode
        self.lights: deque = deque(maxlen=LIGHT_LAG + LIGHT_FRAMES)
        self.reset()

    def reset(self, keep_motion: bool = False) -> None:
        """Forget the feature (``keep_motion``: its shape and place only, learned again at once)."""
        size = EXTENT * self.n_pixels
        self.numerator, self.precision = np.zeros(size), np.zeros(size)
        self.active, self.centre, self.misses = False, 0.0, 0
        self.followed = 0  # frames the feature explained since its shape was learned
        if not keep_motion:
            self.rate = 0.0
            self.travel, self.frames = 0.0, 0  # how far it moved (px) over how many frames, over restarts too
            self.moved = False  # ... far and fast enough for its answers to be taken (MOVED_PX, SPEED_PX)
        self.gain, self.offset_gray = 1.0, 0.0

    # --- the shape -------------------------------------------------------------------------------
    def _columns(self, y: np.ndarray, weights: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One frame's loss of light per column and its precision, smoothed: the ratio to the model."""
        shape = (self.n_rows, self.n_pixels)
        lit = self.gain * values
        precision = (weights * lit * lit).reshape(shape).sum(axis=0)
        loss = (weights * lit * (self.gain * values + self.offset_gray - y)).reshape(shape).sum(axis=0)
        smooth = np.convolve(precision, self.kernel, mode="same")
        return np.convolve(loss, self.kernel, mode="same") / np.maximum(smooth, 1e-300), smooth

    def _learn(self, y: np.ndarray, weights: np.ndarray, values: np.ndarray, centre: float) -> None:
        """Add the frame's loss at the shape's columns it falls on (shared between the two nearest)."""
        loss, precision = self._columns(y, weights, values)
        at = np.clip(self.columns - centre + self.offset, 0.0, self.numerator.size - 1.001)
        low = np.floor(at).astype(int)
        upper = at - low  # split between the two grid columns it falls between
        for index, share in ((low, 1.0 - upper), (low + 1, upper)):
            np.add.at(self.numerator, index, share * loss * precision)
            np.add.at(self.precision, index, share * precision)

    def _shape(self, centre: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The learned loss at each column for the feature at ``centre``, its slope, its variance (inf: not seen)."""
        known = self.precision > 0
        shape = np.where(known, self.numerator / np.where(known, self.precision, 1.0), 0.0)
        at = self.columns - centre + self.offset
        grid = np.arange(shape.size, dtype=np.float64)
        h = np.interp(at, grid, shape)
        slope = np.interp(at, grid[:-1] + 0.5, np.diff(shape))
        lo = np.clip(np.floor(at).astype(int), 0, shape.size - 1)
        hi = np.clip(lo + 1, 0, shape.size - 1)
        inside = (at >= 0) & (at <= shape.size - 1) & known[lo] & known[hi]
        variance = np.where(inside, 1.0 / np.maximum(np.minimum(self.precision[lo], self.precision[hi]), 1e-300),
                            np.inf)
        return h, slope, variance

    # --- the frame -------------------------------------------------------------------------------
    def start(self, evaluator, y: np.ndarray, weights: np.ndarray, x_mm: float, again: bool = False) -> bool:
        """Learn the shape from a frame the uniform light does not explain, at ``x_mm`` (the grating's).
        False (nothing learned) when the loss has no clear part in view: a feature with no edge in
        the field (a lamp dimmed, a new vignetting) is not one that moves, and its place is not measurable.
        ``again``: a feature lost mid-episode, whose motion so far is kept."""
        self.reset(keep_motion=again)
        held = list(self.lights)[:max(len(self.lights) - LIGHT_LAG, 1)]
        self.gain, self.offset_gray = (float(v) for v in np.mean(held, axis=0)) if held else (1.0, 0.0)
        values = evaluator.evaluate(np.array([x_mm]))[0][0]
        loss, precision = self._columns(y, weights, values)
        noise = 1.0 / np.sqrt(np.maximum(precision, 1e-300))
        seen = np.nonzero(np.abs(loss) > SEEN_SIGMAS * noise)[0]
        if seen.size < 3:
            return False
        # a feature coming into view: one end of the line clear (a light shape fixed to the camera shows
        # at both ends or all along; a changed print or blur, all along). Not "seen from the other end":
        # where the print is dark the loss is within the noise (a shadow entering was seen from pixel 11)
        far = max(int(CLEAR_SHARE * self.n_pixels), 1)
        if not again and not (seen[-1] < self.n_pixels - far or seen[0] >= far):  # (one lost mid-field: known)
            return False
        self._learn(y, weights, values, 0.0)
        self.active = True
        return True

    def solve(self, evaluator, y: np.ndarray, weights: np.ndarray, x_start: float, max_step_mm: float) \
            -> Follow | None:
        """Gauss–Newton in (x, c) from the place the motion predicts; None when the system has no x to give."""
        x, centre = x_start, self.centre + self.rate
        shape = (self.n_rows, self.n_pixels)
        result = None
        for _ in range(ITERATIONS):
            values, slopes = evaluator.evaluate(np.array([x]))
            values, slopes = values[0], slopes[0]
            h, slope, variance = self._shape(centre)
            h, slope, variance = (np.broadcast_to(part, shape).reshape(-1) for part in (h, slope, variance))
            seen = np.isfinite(variance)
            lit = self.gain * values
            residual = y - (lit * (1.0 - h) + self.offset_gray)
            # the shape's own uncertainty widens each sample's variance (zero weight where unseen)
            widened = np.where(seen, weights / (1.0 + weights * lit**2 * np.where(seen, variance, 0.0)), 0.0)
            jacobian = np.stack((self.gain * slopes * (1.0 - h), lit * slope), axis=1)
            weighted = jacobian * widened[:, None]
            normal = weighted.T @ jacobian
            try:
                covariance = np.linalg.inv(normal)
            except np.linalg.LinAlgError:
                return None
            if not np.all(np.isfinite(covariance)) or covariance[0, 0] <= 0:
                return None
            step = covariance @ (weighted.T @ residual)
            step[0] = float(np.clip(step[0], -max_step_mm, max_step_mm))
            step[1] = float(np.clip(step[1], -0.1 * self.n_pixels, 0.1 * self.n_pixels))
            used = float(np.count_nonzero(widened))
            cost = float(widened @ (residual * residual))
            lost = lit * h
            visible = float(np.sqrt(np.sum(widened * lost * lost)))
            result = Follow(x, 1.0 / covariance[0, 0], cost / max(used - 2.0, 1.0), cost, centre, visible)
            x, centre = x + step[0], centre + step[1]
            if abs(step[0]) < 1e-7:
                break
        return result

    def accept(self, evaluator, y: np.ndarray, weights: np.ndarray, answer: Follow, reference: float) -> None:
        """The frame was explained: the feature is where it was found, and its shape learns from it
        (at the grating's position)."""
        values = evaluator.evaluate(np.array([reference]))[0][0]
        if self.followed:  # (a frame its shape was just learned on again tells no motion)
            self.travel += answer.centre - self.centre
            self.frames += 1
            self.moved = self.moved or abs(self.travel) >= max(MOVED_PX, SPEED_PX * self.frames)
            self.rate = answer.centre - self.centre
        self.centre, self.misses = answer.centre, 0
        self.followed += 1
        self._learn(y, weights, values, answer.centre)

    def miss(self) -> None:
        self.misses += 1
        if self.misses >= MISSES:
            self.reset()


def follow(tracker, batch, k: int, x_start: float, uniform: FrameSolution, moving: MovingLight,
           here: float = 1.0, reference: float = math.nan) -> FrameSolution:
    """Frame ``k`` with a moving light feature followed, when one is in view and explains it; else
    ``uniform``. The episode holds the light the frames had :data:`LIGHT_LAG` frames before it.
    ``reference``: the grating's reading (NaN: none, and nothing is followed), where the shape is
    learned and the joint solve starts."""
    limit = tracker.chi2_limit * here
    if not math.isfinite(reference):  # no grating read: the frames' own x would trade into the shape
        moving.reset()
        return uniform
    if not moving.active and not (uniform.chi2 > limit and math.isfinite(x_start)):
        moving.lights.append((uniform.gain, uniform.offset) if uniform.free_light else (1.0, 0.0))
        return uniform  # (the common case: nothing but a comparison and the light kept)
    weights = batch.weights(k)
    # samples the robust solve set aside are left out, unless so many that the uniform answer is not
    # trusted: then they were the feature itself (a shadow's edge taken for a transient)
    kept = uniform if tracker.untrusted(uniform) is None else FrameSolution(uniform.x_mm, 0.0, 0.0, 0)
    if kept.rejected_mask is not None:
        weights = weights * ~kept.rejected_mask
    weights = np.asarray(weights, dtype=np.float64).reshape(-1)
    y = np.asarray(batch.frames[k], dtype=np.float64).reshape(-1)
    restart = first = not moving.active
    for _ in range(2):  # a feature lost mid-episode (its place and x traded) is learned again at once
        if restart:
            if not moving.start(tracker.evaluator, y, weights, reference, again=not first):
                return uniform
        answer = moving.solve(tracker.evaluator, y, weights, reference, tracker.settings.max_step_mm)
        if _sane(answer, uniform, moving, tracker, limit, x_start):
            break
        moving.miss()
        if restart or not uniform.chi2 > limit:
            return uniform
        restart = True
    moving.accept(tracker.evaluator, y, weights, answer, reference)
    if not moving.moved:  # (followed, not yet seen to move: the uniform answer stands)
        return uniform
    return FrameSolution(answer.x_mm, tracker.settings.sigma_gray * math.sqrt(answer.chi2), answer.information,
                         ITERATIONS, moving.gain, moving.offset_gray, answer.chi2, kept.rejected, False, 0.0,
                         answer.cost, kept.rejected_mask, kept.rejected_weights_exact,
                         transient_px=kept.transient_px, transient_share=kept.transient_share,
                         transient_at=kept.transient_at, moving=True)


def _sane(answer: Follow | None, uniform: FrameSolution, moving: MovingLight, tracker, limit: float,
          x_start: float) -> bool:
    """The feature explains the frame (χ² within the single-frame limit), is seen in it, and its
    place and x separate: a finite bound within :data:`SANE_BOUND` of the uniform light's, x within
    a quarter period of the prediction, the place where the feature's motion carries it."""
    return answer is not None and answer.chi2 <= limit and answer.visible > SEEN_SIGMAS \
        and math.isfinite(answer.information) and answer.information > 0 \
        and abs(answer.x_mm - x_start) < tracker.quarter_period_mm \
        and answer.information * SANE_BOUND**2 >= uniform.information \
        and (moving.followed < 2 or abs(answer.centre - moving.centre - moving.rate) < JUMP_PX)
