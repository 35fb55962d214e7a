"""A shadow's band crossing the field: its shape in two numbers and two edges, learned and followed.

A cable (an arm, a rod) between the lamp and the print casts a band of shadow fixed to neither the
camera nor the print: the print slides under it, and it moves when the cable swings. Its edges are
soft (the lamp is not a point: a penumbra), so the light lost at column p is

    h(p) = d · B(p),   B(p) = ½ [erf((p − l)/(√2 e)) − erf((p − r)/(√2 e))]

with the band's edges l < r (pixels, moving every frame), its depth d and softness e (the cable's,
the same on every frame). A single edge entering (a hand) is a band wider than the field. On a
line shorter than a period no field of a frame's own separates from x (a Legendre field that
describes the shadow costs 30–50× the bound, docs/robustness.md), and a shape learned free per
column is built from few frames at its edges, needs the grating to learn at, and leaves its error
out of the bound (1.4–2.2× the clean bound with the grating, not followed without it: 25–83×).
A shape of two numbers shared by every frame is learned from the frames themselves, grating or not:
the print's pattern moves with x, the band with its edges, and its shape is the same wherever it is.

Each frame solves (x, l, r, d, e) by Levenberg–Marquardt, with what earlier frames taught as priors:

- the shape (d, e): solved jointly over the last :data:`WINDOW` frames followed (each its own x and
  edges, profiled out), its information the prior of the next frame; kept, halved, for the next
  pass (the same cable comes back: its width too, as the band's first frames are searched);
- the edges: a constant-velocity Kalman filter on (l, r, speed), its acceleration's spread
  :data:`ACCEL_PX`, so the band's centre crossing (where x and the place nearly trade) leans on its
  motion; an edge out of view keeps the speed of the one in view.

The bound is the joint one (x with everything else profiled out, priors included): the shape's and
the motion's uncertainty is in it. The light's gain and offset are held at those the frames had
before the episode (:data:`LIGHT_LAG`). The answer is taken only when it explains the frame (χ²
within the single-frame limit), the band is seen in it, its edges are where the motion carries them,
and it has been seen to move (a lamp's vignetting fixed to the camera is no band crossing the field).
"""

from __future__ import annotations

import copy
import functools
import math
from collections import deque
from dataclasses import dataclass
from typing import TypeGuard

import numpy as np
from scipy.special import erf

from graytrack.core.solvers import FrameSolution

ROOT_PI, ROOT_2 = math.sqrt(math.pi), math.sqrt(2.0)
ITERATIONS = 12
SEEN_SIGMAS = 5.0  # the band seen in a frame: its loss in view beyond this many of its noise
LEAVING_BOUNDS = 1.0  # a band seen to move is followed out of view while its loss bends x beyond this many bounds
# (its tail, 2-4 of its noise, bent the uniform light's answers 3.5-4 bounds as it left, at a χ² within its noise)
EARLY_SPREADS = 3.0  # a band seen before: looked for at a frame's χ² beyond this many of its spreads
STRAINED_SPREADS = 1.0  # a followed answer's χ² beyond this many spreads: the band loosely held is tried too (at
# three, a 16-row strip's band whose shape its tail misled is freed a frame later: 1.38x its bound, 1.17x at one)
MISSES = 3  # frames in a row the band does not explain before the episode ends
GATE_SIGMAS = 5.0  # an edge beyond this many of its predicted spread: not the band followed
MOVED_PX = 2.0  # the band's answer is taken once it has moved this far, at SPEED_PX a frame or more on
SPEED_PX = 1.0  # average (a lamp's vignetting wandered ±1.6 px, then drifted past 2 px after 30 frames)
YOUNG_STEPS = 5  # a band followed over fewer steps than this, not yet seen to move, answers where the uniform light
# does not explain the frame (with its tail alone in view its depth grows before its place moves: 3 steps did not move)
SANE_BOUND = 10.0  # a joint bound beyond this many of the uniform light's: x and the band do not separate
ACCEL_PX = 0.3  # px/frame²: the spread of the band's acceleration (a swinging cable's speed changes slowly)
WOBBLE_PX = 0.3  # px/frame: each edge's own wander about the common motion (the width may change a little)
WIDTH_SEEN_PX = 2.0  # a band's width is kept when both its edges were placed this well
PLACE_SPREAD = 0.1  # of the field: the spread of the edges' places when a band is found
RATE_PX = 20.0  # px/frame: the spread of its speed when an episode starts (either way)
MIN_DEPTH = 0.03  # a band shallower than this is no shadow to follow (a blur's residual on a 16-row strip, fitted
# as a band 0.1-0.5 % deep, took the focus term's frames); the uniform light and its field describe such a dip
# (the depth the band reaches, :func:`peak_depth`: a blob whose edges are softer than it is wide never gets near its
# nominal depth; row banding on a 16-row strip, against the light held, was fitted as one 4-9 % deep but 0.5-2 % at its
# peak, 4-26 px wide and 22-94 px soft, and its next frame's jump of 10-50 px was taken for motion: 7 frames of a
# steady run flagged `light`, 2 of its calibration's 15 and 8 bounds off)
MIN_EDGE_PX, MIN_WIDTH_PX = 2.0, 1.0  # a penumbra narrower than 2 px is no soft shadow (a smudge's edges fitted
# at half a pixel take it for a band: 8.1x the bound without the grating, 5.5x with this floor)
WINDOW = 10  # frames: the shape is solved jointly over the last frames followed (each its own x and edges)
KEEP = 0.5  # the share of a pass's information on the shape the next pass starts from (the cable may have moved)
LIGHT_LAG, LIGHT_FRAMES = 5, 20  # the light held: its average over LIGHT_FRAMES frames, LIGHT_LAG before the
# episode (an edge is felt before a frame asks, and a light solved on those frames traded against it:
# a gain 3 % low placed a shadow's frames 5-10 bounds off)
END_SHARE = 0.2  # a band's first frame leaves this share of one end of the line clear
SMOOTH_PX = 5  # columns summed to tell where the light is lost
GRID_EDGES = (0.05, 0.1, 0.2, 0.35)  # the start's search: softness and width as shares of the field
GRID_WIDTHS = (0.25, 0.5, 1.0, 3.0)
FIXED = ("n_rows", "n_pixels", "columns", "lights", "saved", "last")  # MovingBand's fields a rewind keeps
TRANSITION = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])  # (left, right, speed) a frame on
PROCESS = ACCEL_PX**2 * np.outer([0.5, 0.5, 1.0], [0.5, 0.5, 1.0]) + np.diag([WOBBLE_PX**2, WOBBLE_PX**2, 0.0])


@dataclass
class BandAnswer:
    """The joint answer on one frame."""

    params: np.ndarray  # (x mm, left edge px, right edge px, depth, softness px)
    covariance: np.ndarray  # of the five, the priors included
    chi2: float
    cost: float
    visible: float  # the band's loss in view, in units of its noise
    bends: float  # how far that loss, left out, would move x: in x's bounds
    predicted: np.ndarray  # the edges' places the motion predicted, and their covariance
    predicted_cov: np.ndarray

    @property
    def information(self) -> float:
        return 1.0 / self.covariance[0, 0]


def band(columns: np.ndarray, left: float | np.ndarray, right: float | np.ndarray,
         edge: float) -> tuple[np.ndarray, ...]:
    """B at each column for a band between ``left`` and ``right`` (its half-depth points), and its
    derivatives by the two edges' places and by the softness."""
    scale = ROOT_2 * edge
    a, b = (columns - left) / scale, (columns - right) / scale
    ga, gb = np.exp(-a * a) / ROOT_PI, np.exp(-b * b) / ROOT_PI
    return _loss(a, b), -ga / scale, gb / scale, -(ga * a - gb * b) / edge


def _loss(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """B from the columns' distances to the two edges, in units of √2 e."""
    return 0.5 * (erf(a) - erf(b))


class MovingBand:
    """One band's state: its shape (kept across episodes) and, during one, its edges and motion.

    The edges are followed apart (a constant-velocity Kalman filter on both places and a common
    speed): while one edge alone is in view the other's place is unknown, and a band described by
    its centre and width traded the two (its width grew instead of the band moving, and when the
    other edge came the solve could not walk back along that valley: 300 µm off)."""

    def __init__(self, n_rows: int, n_pixels: int) -> None:
        self.n_rows, self.n_pixels = n_rows, n_pixels
        self.columns = np.tile(np.arange(n_pixels, dtype=np.float64), n_rows)
        self.lights: deque = deque(maxlen=LIGHT_LAG + LIGHT_FRAMES)  # the last frames' (gain, offset)
        self.shape = np.array([0.0, 1.0])  # (depth, softness px): the prior each frame's solve holds it to
        self.shape_information = np.zeros((2, 2))
        self.loose = self.shape, self.shape_information  # the episode's own prior on the shape
        self.kept: tuple[np.ndarray, np.ndarray, float | None] | None = None  # (shape, information, width): the
        # last pass's (or the band's before it was lost)
        self.window: deque = deque(maxlen=WINDOW)  # the last frames followed: [y, weights, x, left, right]
        self.last: np.ndarray | None = None  # the last frame taken, and the state before it (see rewind)
        self.saved: dict = {}
        self.moved: bool = False  # (the episode's state: reset() sets it, and reads it for the episode it ends)
        self.width: tuple[float, float] = (0.0, math.inf)
        self.reset()

    def reset(self) -> None:
        """The episode ends (its shape is kept as the next one's prior: the same cable comes back)."""
        if len(self.window) >= WINDOW // 2 and self.moved:  # (its width only if both its edges were seen)
            width = self.width[0] if self.width[1] <= WIDTH_SEEN_PX**2 else None
            self.kept = self.shape.copy(), KEEP * self.shape_information, width
        self.window.clear()
        self.active, self.misses, self.followed = False, 0, 0
        self.motion, self.motion_cov = np.zeros(3), np.eye(3)  # (left, right, speed)
        self.steps: list[float] = []  # the place's steps, frame to frame, until it is seen to move
        self.moved = False
        self.entering = False  # found with an edge beyond the line's end: coming into view as a shadow does
        self.width = (0.0, math.inf)  # the band's width where both edges were best seen, and their larger variance
        self.gain, self.offset_gray = 1.0, 0.0

    # --- the start ---------------------------------------------------------------------------------
    def start(self, evaluator, y: np.ndarray, weights: np.ndarray, x_mm: float, again: bool = False) -> bool:
        """Find the band in a frame the uniform light does not explain, at ``x_mm``: its best place,
        width and softness on a grid (the depth is linear), or its place alone for the last pass's
        band. False: no band explains the frame better than the uniform light by a clear margin.
        ``again``: a band lost mid-pass, whose motion is kept."""
        speed, speed_var, moved = float(self.motion[2]), float(self.motion_cov[2, 2]), self.moved
        self.reset()
        held = list(self.lights)[:max(len(self.lights) - LIGHT_LAG, 1)]
        self.gain, self.offset_gray = (float(v) for v in np.mean(held, axis=0)) if held else (1.0, 0.0)
        lit = self.gain * evaluator.evaluate(np.array([x_mm]))[0][0]
        lost = lit + self.offset_gray - y
        n = self.n_pixels
        centres = np.arange(-1.5 * n, 2.5 * n + 1, max(n / 50.0, 1.0))
        # the last pass's band (its place, and its width if not known), held to what it learned, unless
        # a band of its own explains the frame better by far
        widths = [w * n for w in GRID_WIDTHS]
        grid, found = _search(self.columns[:n], centres, lit, lost, weights,
                              [(w, e * n) for w in widths for e in GRID_EDGES])
        if self.kept is not None:
            shape, information, width = self.kept
            known = _search(self.columns[:n], centres, lit, lost, weights,
                            [(w, shape[1]) for w in ([width] if width is not None else widths)], shape[0])
            if known[1] is not None and known[0] + SEEN_SIGMAS**2 >= grid:
                found, self.loose = known[1], (shape.copy(), information.copy())
                moved = True  # (the band seen to move before, coming back)
        if found is None:
            return False
        if self.kept is None or found is not known[1]:
            self.loose = np.array([found[1], found[3]]), np.diag([1.0, 1.0 / n**2])  # held loosely
        self.shape, self.shape_information = self.loose[0].copy(), self.loose[1].copy()
        centre, width = found[0], found[2]
        self.motion = np.array([centre - 0.5 * width, centre + 0.5 * width, 0.0])
        # the edges as the search placed them (one out of view held no looser: a field's width of spread
        # let it wander and cost the followed frames; when it comes into view, a loosened solve or a
        # search anew finds it)
        self.motion_cov = np.diag([(PLACE_SPREAD * n) ** 2, (PLACE_SPREAD * n) ** 2, RATE_PX**2])
        if again:  # a band lost mid-pass (an edge came into view far from where it was held) keeps its motion
            self.motion[2], self.motion_cov[2, 2] = speed, speed_var
        self.moved = moved and (again or self.kept is not None)
        self.entering = bool(self.motion[0] < 0.0 or self.motion[1] > n - 1.0)
        self.active = True
        return True

    # --- the frame ---------------------------------------------------------------------------------
    def predict(self) -> tuple[np.ndarray, np.ndarray]:
        """Where the motion carries the edges, and their covariance (the motion's, a frame on)."""
        if self.followed == 0:
            return self.motion.copy(), self.motion_cov.copy()
        return TRANSITION @ self.motion, TRANSITION @ self.motion_cov @ TRANSITION.T + PROCESS

    def solve(self, evaluator, y: np.ndarray, weights: np.ndarray, x_start: float, max_step_mm: float) \
            -> BandAnswer | None:
        """Levenberg–Marquardt in (x, left, right, depth, softness) from the predicted edges, with
        the priors; None when the system has no x to give."""
        state, state_cov = self.predict()
        prior = np.zeros((5, 5))
        try:
            prior[1:3, 1:3] = np.linalg.inv(state_cov[:2, :2])
        except np.linalg.LinAlgError:
            return None
        prior[3:, 3:] = self.shape_information
        anchor = np.concatenate(([x_start], state[:2], self.shape))
        params, damping = anchor.copy(), 1e-3
        current = self._linearise(evaluator, y, weights, params, prior, anchor)
        for _ in range(ITERATIONS):
            total, residual, jacobian = current[:3]
            weighted = jacobian * weights[:, None]
            normal = weighted.T @ jacobian + prior
            gradient = weighted.T @ residual - prior @ (params - anchor)
            for _ in range(6):
                try:
                    step = np.linalg.solve(normal + damping * np.diag(np.diag(normal)), gradient)
                except np.linalg.LinAlgError:
                    return None
                step[0] = float(np.clip(step[0], -max_step_mm, max_step_mm))
                trial = _bounded(params + step)
                candidate = self._linearise(evaluator, y, weights, trial, prior, anchor)
                if candidate[0] <= total:
                    params, current, damping = trial, candidate, max(damping / 4.0, 1e-6)
                    break
                damping *= 8.0
            else:
                break
            if abs(step[0]) < 1e-7 and total - current[0] < 1e-3:
                break
        total, residual, jacobian, cost, visible, bends = current
        try:
            covariance = np.linalg.inv((jacobian * weights[:, None]).T @ jacobian + prior)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(covariance)) or covariance[0, 0] <= 0:
            return None
        used = float(np.count_nonzero(weights))
        return BandAnswer(params, covariance, cost / max(used - 2.0, 1.0), cost, visible, bends, state[:2],
                          state_cov[:2, :2])

    def _linearise(self, evaluator, y: np.ndarray, weights: np.ndarray, params: np.ndarray, prior: np.ndarray,
                   anchor: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, float, float, float]:
        """(cost with the priors, residual, Jacobian, the data's cost, the band's loss in its noise, and
        in x's bounds the shift that loss would cause left out) at ``params``."""
        residual, jacobian, lost = _frame(evaluator, self.gain, self.offset_gray, self.columns, y, params)
        cost = float(weights @ (residual * residual))
        off = params - anchor
        slope = weights * jacobian[:, 0]
        bends = abs(float(slope @ lost)) / math.sqrt(max(float(slope @ jacobian[:, 0]), 1e-300))
        return cost + float(off @ prior @ off), residual, jacobian, cost, float(np.sqrt(weights @ (lost * lost))), bends

    def sane(self, answer: BandAnswer | None, uniform_information: float, limit: float) -> TypeGuard[BandAnswer]:
        """The band explains the frame, is seen in it, its edges are where the motion carries them,
        and it leaves x a bound."""
        if answer is None or not (answer.chi2 <= limit and peak_depth(*answer.params[1:]) >= MIN_DEPTH):
            return False
        leaving = self.moved and self.followed and answer.bends > LEAVING_BOUNDS
        if not (answer.visible > SEEN_SIGMAS or leaving):
            return False
        if not (math.isfinite(answer.information) and answer.information * SANE_BOUND**2 >= uniform_information):
            return False
        if self.followed == 0:
            return True
        jump = answer.params[1:3] - answer.predicted
        spread = np.diag(answer.predicted_cov) + np.diag(answer.covariance)[1:3]
        return bool(np.all(jump * jump <= GATE_SIGMAS**2 * spread))

    def accept(self, evaluator, y: np.ndarray, weights: np.ndarray, answer: BandAnswer, counted: bool = True) -> None:
        """The frame was explained: the motion takes the edges' update (the speed by its regression
        on them), and the shape is solved again over the window. ``counted``: its step tells the
        motion (not when it was solved loosely held: an edge let go jumps)."""
        state, state_cov = self.predict()
        edges, edges_cov = answer.params[1:3], answer.covariance[1:3, 1:3]
        across = state_cov[:, :2] @ np.linalg.inv(state_cov[:2, :2])
        before = self.motion[:2].copy()
        self.motion = state + across @ (edges - state[:2])
        self.motion_cov = state_cov - across @ (state_cov[:2, :2] - edges_cov) @ across.T
        self.motion[:2], self.motion_cov[:2, :2] = edges, edges_cov
        if self.followed and not self.moved and counted:
            seen = int(np.argmin(np.diag(edges_cov)))  # the edge in view (the other may wander unseen)
            self.steps.append(float(edges[seen] - before[seen]))
            self.moved = _moving(np.array(self.steps))
        spread = float(max(edges_cov[0, 0], edges_cov[1, 1]))
        if spread < self.width[1]:  # (near the field's ends one edge is out of view and wanders)
            self.width = float(edges[1] - edges[0]), spread
        self.misses = 0
        self.followed += 1
        self.window.append([y.copy(), weights.copy(), *map(float, answer.params[:3])])  # (a live batch is reloaded)
        refined = refine(evaluator, self.gain, self.offset_gray, self.columns, self.window, answer.params[3:],
                         *self.loose)
        if refined is not None:
            self.shape, self.shape_information = refined

    @property
    def young(self) -> bool:
        """Not yet followed over the frames it takes to be seen to move (:data:`MOVED_PX` at
        :data:`SPEED_PX` a frame): its answer is taken, flagged, where the uniform light does not
        explain the frame (a first pass's first frames: the band's answers were 0-2 µm off at a
        2 µm bound, the uniform light's, which stood until the band had moved, 18-46 µm). Only a band
        coming into view from beyond the line's end, as a shadow does: one found whole inside the field
        (a smudge on the print the uniform light had lost, 400 µm off) answered 10 bounds off, frame
        after frame, each frame a new episode."""
        return self.entering and not self.moved and len(self.steps) < YOUNG_STEPS

    def at_both_ends(self, evaluator, y: np.ndarray, weights: np.ndarray, x_mm: float) -> bool:
        """The light lost at ``x_mm`` (a first frame's joint answer: without the grating the last
        frames' x, which the band's edge had bent 20 µm, showed the print's misfit at both ends) shows
        at both ends of the line: a band comes into view from one end, and a light shape fixed to the
        camera (a lamp's vignetting) shows at both."""
        lit = self.gain * evaluator.evaluate(np.array([x_mm]))[0][0]
        return _both_ends(lit, lit + self.offset_gray - y, weights, self.n_rows, self.n_pixels)

    def taking(self, y: np.ndarray) -> None:
        """A frame is about to be taken: the state before it is kept (the tracker may solve the same
        frame again, re-acquiring it, and a frame taken twice read as a band that stood still: its
        speed went to zero, its spread to a third of a pixel)."""
        self.saved = copy.deepcopy({key: value for key, value in vars(self).items() if key not in FIXED})
        self.last = y.copy()

    def rewind(self, y: np.ndarray) -> None:
        """The frame last taken comes again: back to the state before it."""
        if self.last is not None and self.saved and self.last.shape == y.shape and np.array_equal(self.last, y):
            vars(self).update(copy.deepcopy(self.saved))

    def loosen(self) -> bool:
        """Hold the shape and the edges loosely (False: nothing followed yet, nothing to loosen)."""
        if not self.followed:
            return False
        self.shape_information = self.loose[1].copy()
        self.motion_cov = self.motion_cov + np.diag([float(self.n_pixels**2)] * 2 + [0.0])
        return True

    def miss(self) -> None:
        self.misses += 1
        if self.misses >= MISSES:
            self.reset()


def peak_depth(left: float, right: float, depth: float, edge: float) -> float:
    """The share of the light the band takes at its middle: ``depth · erf(w / (2√2 e))`` for its
    width w = right − left and softness e. A shadow's band is several pixels wide and its edges
    sharper than that (a cable's: 48 px wide, 16 px soft, 0.87 of its depth reached); a band
    softer than it is wide is a faint broad dip, which the uniform light and a frame's own offset
    describe (row banding's), and is no shadow whatever its nominal depth."""
    return float(depth * erf((right - left) / (2.0 * ROOT_2 * max(edge, 1e-12))))


def _frame(evaluator, gain: float, offset: float, columns: np.ndarray, y: np.ndarray,
           params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame's residual, its Jacobian by (x, left, right, depth, softness), and the light the band takes."""
    x, left, right, depth, edge = params
    values, slopes = (part[0] for part in evaluator.evaluate(np.array([x])))
    lit = gain * values
    value, by_left, by_right, by_edge = band(columns, left, right, edge)
    residual = y - (lit * (1.0 - depth * value) + offset)
    jacobian = np.stack((gain * slopes * (1.0 - depth * value), -lit * depth * by_left, -lit * depth * by_right,
                         -lit * value, -lit * depth * by_edge), axis=1)
    return residual, jacobian, lit * depth * value


def _moving(steps: np.ndarray) -> bool:
    """The place has moved :data:`MOVED_PX` or more, at :data:`SPEED_PX` a frame or more on average
    (steps solved loosely held not counted: a lamp's vignetting, taken for a band near the line's
    end and let go, jumped 11 px)."""
    return abs(float(steps.sum())) >= max(MOVED_PX, SPEED_PX * steps.size)


def _both_ends(lit: np.ndarray, lost: np.ndarray, weights: np.ndarray, n_rows: int, n_pixels: int) -> bool:
    """The light lost shows beyond :data:`SEEN_SIGMAS` of its noise (over :data:`SMOOTH_PX` columns)
    within :data:`END_SHARE` of both ends of the line."""
    shape = (n_rows, n_pixels)
    precision = (weights * lit * lit).reshape(shape).sum(axis=0)
    across = (weights * lit * lost).reshape(shape).sum(axis=0)
    box = np.ones(SMOOTH_PX)
    precision, across = np.convolve(precision, box, mode="same"), np.convolve(across, box, mode="same")
    seen = np.abs(across) > SEEN_SIGMAS * np.sqrt(np.maximum(precision, 1e-300))
    far = max(int(END_SHARE * n_pixels), 1)
    return bool(seen[:far].any() and seen[-far:].any())


@functools.lru_cache(maxsize=64)
def _grid_loss(columns: bytes, centres: bytes, width: float, edge: float) -> np.ndarray:
    """B of a band ``width`` wide and ``edge`` soft at each of the ``centres`` over the ``columns`` (as
    raw float64 bytes, a cache key): the start's grid is the same on every search of a line, and its
    erf calls were most of a run's time where no band was ever found (a glare: 21 of 28 s)."""
    line, middle = np.frombuffer(columns)[None, :], np.frombuffer(centres)[:, None]
    scale, left, right = ROOT_2 * edge, middle - 0.5 * width, middle + 0.5 * width
    loss = _loss((line - left) / scale, (line - right) / scale)
    loss.flags.writeable = False
    return loss


def _search(columns: np.ndarray, centres: np.ndarray, lit: np.ndarray, lost: np.ndarray, weights: np.ndarray,
            shapes: list[tuple[float, float]], depth: float | None = None) -> tuple[float, tuple[float, ...] | None]:
    """The χ² gained and the (centre, depth, width, softness) on the grid that best explains the light
    ``lost`` (the depth solved, linear, unless given); None when none gains :data:`SEEN_SIGMAS`². ``columns``:
    one row's (the samples are every row's columns in turn)."""
    best, found = SEEN_SIGMAS**2, None
    # B on one row's columns (the samples are the rows' columns row after row): the same numbers as on every
    # sample, for a 16-row strip's 16th of the erf calls (a search on each frame of a rolling shutter's
    # calibration took minutes), and without the derivatives a search never reads.
    # B is the same on every row's column, so the sums over the samples are the columns' sums over the rows
    # taken first: a product with one row's columns, not with the samples' tile of B
    rows = lit.size // columns.size
    weighted_lit = weights * lit
    lit_lost = (weighted_lit * lost).reshape(rows, columns.size).sum(axis=0)
    lit_power = (weighted_lit * lit).reshape(rows, columns.size).sum(axis=0)
    for width, edge in shapes:
        loss = _grid_loss(columns.tobytes(), centres.tobytes(), float(width), float(edge))
        across, power = loss @ lit_lost, (loss * loss) @ lit_power
        if depth is None:
            depths = across / np.maximum(power, 1e-300)
            gain = across * depths
        else:
            gain, depths = 2 * depth * across - depth * depth * power, np.full(centres.size, depth)
        gain = np.where((depths >= MIN_DEPTH) & (depths < 1), gain, 0.0)
        i = int(np.argmax(gain))
        if gain[i] > best:
            best, found = float(gain[i]), (float(centres[i]), float(depths[i]), width, edge)
    return best, found


def refine(evaluator, gain: float, offset: float, columns: np.ndarray, window, shape: np.ndarray,
           prior_shape: np.ndarray, prior_information: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The shape (depth, softness) solved jointly over the window's frames, each its own x and
    edges (eliminated by their Schur complements), by Levenberg–Marquardt; the window's x and edges
    updated in place. Returns (shape, its information with every x and edge profiled out); None: no
    solution. A shape carried frame to frame by its linearised information alone kept what the
    first frames (one tail in view) made of it: 10-17 µm off at a bound of 2-5 mid-pass."""
    locals_ = [np.array(item[2:5]) for item in window]
    damping = 1e-3

    def linear(shape, locals_):
        total = float((shape - prior_shape) @ prior_information @ (shape - prior_shape))
        parts = []
        for item, local in zip(window, locals_):
            residual, jacobian, _ = _frame(evaluator, gain, offset, columns, item[0], np.concatenate((local, shape)))
            total += float(item[1] @ (residual * residual))
            parts.append((jacobian * item[1][:, None], jacobian, residual))
        return total, parts

    def normal(parts, shape):
        joint, rhs, blocks = prior_information.copy(), -prior_information @ (shape - prior_shape), []
        for weighted, jacobian, residual in parts:
            joint += weighted[:, 3:].T @ jacobian[:, 3:]
            rhs += weighted[:, 3:].T @ residual
            blocks.append((weighted[:, :3].T @ jacobian[:, :3], weighted[:, :3].T @ jacobian[:, 3:],
                           weighted[:, :3].T @ residual))
        return joint, rhs, blocks

    shape = shape.copy()
    total, parts = linear(shape, locals_)
    for _ in range(4):
        joint, rhs, blocks = normal(parts, shape)
        for _ in range(6):
            reduced, reduced_rhs, inverses = joint + damping * np.diag(np.diag(joint)), rhs.copy(), []
            try:
                for u, m, g in blocks:
                    inverse = np.linalg.inv(u + damping * np.diag(np.diag(u)) + 1e-9 * np.eye(3))
                    reduced -= m.T @ inverse @ m
                    reduced_rhs -= m.T @ inverse @ g
                    inverses.append(inverse)
                step = np.linalg.solve(reduced, reduced_rhs)
            except np.linalg.LinAlgError:
                return None
            trials = [_bounded(np.concatenate((local + inverse @ (g - m @ step), shape + step)))
                      for local, inverse, (u, m, g) in zip(locals_, inverses, blocks)]
            trial_shape, trial_locals = trials[0][3:], [trial[:3] for trial in trials]
            trial_total, trial_parts = linear(trial_shape, trial_locals)
            if trial_total <= total:
                shape, locals_, total, parts, damping = trial_shape, trial_locals, trial_total, trial_parts, damping / 4
                break
            damping *= 8.0
        else:
            break
    joint, rhs, blocks = normal(parts, shape)
    try:
        information = joint - sum(m.T @ np.linalg.solve(u + 1e-9 * np.eye(3), m) for u, m, g in blocks)
    except np.linalg.LinAlgError:
        return None
    for item, local in zip(window, locals_):
        item[2:5] = map(float, local)
    return shape, information


def _bounded(params: np.ndarray) -> np.ndarray:
    """Edges in order a pixel or more apart, a depth within (0, 1), a softness of half a pixel or more."""
    out = params.copy()
    out[2] = max(out[2], out[1] + MIN_WIDTH_PX)
    out[3] = min(max(out[3], 0.0), 0.99)
    out[4] = max(out[4], MIN_EDGE_PX)
    return out


def follow(tracker, batch, k: int, x_start: float, uniform: FrameSolution, moving: MovingBand,
           here: float = 1.0, reference: float = math.nan) -> FrameSolution:
    """Frame ``k`` with a band of shadow followed, when one is in view and explains it; else
    ``uniform``. ``reference``: the grating's reading (NaN: none), where a band is looked for on
    its first frame (else where the tracker's motion puts the frame: the uniform answer had traded
    x for the band's edge)."""
    limit = tracker.chi2_limit * here
    # a band seen before is looked for at three of one frame's χ² spreads (its edge coming in bent x
    # 13 µm, 6 bounds, at a χ² within five): one frame in 700 by chance, and only after a band
    spread = (tracker.chi2_limit / tracker.chi2_calibration - 1.0) / 5.0  # one frame's χ² spread, relative
    asks = tracker.chi2_calibration * here * (1.0 + EARLY_SPREADS * spread) if moving.kept else limit
    strained = tracker.chi2_calibration * here * (1.0 + STRAINED_SPREADS * spread)
    if not moving.active and not (uniform.chi2 > asks and math.isfinite(x_start)):
        moving.lights.append((uniform.gain, uniform.offset_gray) if uniform.free_light else (1.0, 0.0))
        return uniform  # (the common case: nothing but a comparison and the light kept)
    weights = batch.weights(k)
    # samples the robust solve set aside are left out, unless so many that the uniform answer is not
    # trusted: then they were the band itself (a shadow's edge taken for a transient)
    kept = uniform if tracker.untrusted(uniform) is None else FrameSolution(uniform.x_mm, 0.0, 0.0, 0)
    if kept.rejected_mask is not None:
        weights = weights * ~kept.rejected_mask
    weights = np.asarray(weights, dtype=np.float64).reshape(-1)
    y = np.asarray(batch.frames[k], dtype=np.float64).reshape(-1)
    moving.rewind(y)
    at = reference if math.isfinite(reference) else x_start
    answer = None
    for how in ("followed", "loosened", "anew"):
        # a band whose shape or motion changed (its width, unknown while one edge alone was in view,
        # shows when the other comes) is solved again loosely held; one lost is looked for anew
        if how == "anew":
            # (a band seen to move and lost is looked for at once: an edge out of view has no slope to
            # be found by, and the uniform light takes the one coming in for x at a χ² within its limit)
            again = moving.moved
            if not ((uniform.chi2 > asks or again) and moving.start(tracker.evaluator, y, weights, at, again)):
                break
            if math.isfinite(reference) and not again and moving.at_both_ends(tracker.evaluator, y, weights, at):
                moving.reset()  # (with the grating, at its reading; without, at the first answer: below)
                break
        elif not moving.active or (how == "loosened" and not moving.loosen()):
            continue
        trial = moving.solve(tracker.evaluator, y, weights, at, tracker.settings.max_step_mm)
        if moving.sane(trial, uniform.information, limit) and abs(trial.params[0] - x_start) \
                < tracker.quarter_period_mm:
            first = not (moving.followed or moving.moved or math.isfinite(reference))
            if first and moving.at_both_ends(tracker.evaluator, y, weights, trial.params[0]):
                moving.reset()
                break
            answer = trial
            if how == "followed" and trial.chi2 > strained and moving.followed:
                how, answer = _loosened_if_better(tracker, moving, y, weights, at, uniform.information, limit, trial)
            break
    if answer is None:
        moving.miss()
        return uniform
    moving.taking(y)
    moving.accept(tracker.evaluator, y, weights, answer, how == "followed")
    if not (moving.moved or (moving.young and uniform.chi2 > limit)):
        return uniform  # (followed, given its frames to move and not seen to: the uniform answer stands)
    x = float(answer.params[0])
    return FrameSolution(x, tracker.settings.sigma_gray * math.sqrt(answer.chi2), answer.information,
                         ITERATIONS, moving.gain, moving.offset_gray, answer.chi2, kept.rejected_px, False, 0.0,
                         answer.cost, kept.rejected_mask, kept.rejected_weights_exact,
                         transient_px=kept.transient_px, transient_share=kept.transient_share,
                         transient_at=kept.transient_at, moving=True)


def _loosened_if_better(tracker, moving: MovingBand, y: np.ndarray, weights: np.ndarray, at: float,
                        uniform_information: float, limit: float, followed: BandAnswer) -> tuple[str, BandAnswer]:
    """The frame solved again with the band loosely held, taken when it explains the frame better by
    :data:`SEEN_SIGMAS`² of χ²: a followed answer within the limit but strained (beyond
    :data:`STRAINED_SPREADS` of its spreads) may be a band whose shape, learned while its tail alone
    was in view, is wrong (a 16-row strip's band read 0.54 deep and 18 px wide for 0.2 and 48 while
    its second edge came in, and its answers were 5-8 bounds off while the χ² stayed within its limit)."""
    held = moving.shape_information.copy(), moving.motion_cov.copy()
    moving.loosen()
    trial = moving.solve(tracker.evaluator, y, weights, at, tracker.settings.max_step_mm)
    if moving.sane(trial, uniform_information, limit) and trial.cost + SEEN_SIGMAS**2 < followed.cost \
            and abs(trial.params[0] - followed.params[0]) < tracker.quarter_period_mm:
        return "loosened", trial
    moving.shape_information, moving.motion_cov = held
    return "followed", followed
