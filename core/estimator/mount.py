"""The camera on its mount: a step of the image against the carriage that no motion of the stage makes.

Without the grating, a frame places the image, not the carriage: the camera's place on the carriage is
a state no frame observes, and a knock on the mount (the image jumps tens of µm and stays) passes every
frame's test, because one frame cannot tell a step of the place from the stage's own acceleration. The
frames after it can: the stage reaches a new position only through its velocity, so a step with the
same velocity before and after it is one the stage makes only by accelerating hard, and no harder than
it can. This is the geometry family's jump decided one frame late, over the last four frames' positions.

The test (:func:`step_test`): over four frames' positions ``p`` at times ``t`` with variances ``var``,
the weighted least-squares fit of a line with a step between the second and the third frame; the step
``d = Σ cᵢ pᵢ`` is a functional that a line leaves at zero, so for any stage motion x(t) it equals
``∫ x″(s) K(s) ds`` with the Peano kernel ``K(s) = Σ cᵢ (tᵢ − s)₊``: a stage accelerating at most ``a``
makes a step of at most ``a · ∫|K|`` (the allowance). A step beyond the allowance by more than the
two-sided quantile of its noise at the false-alarm rate is the mount's: the camera's place jumps by
it, with the variance of the fit and of what the stage may still have done within its allowance
(uniform over ±allowance), and the frames carry that in their bound from then on.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from graytrack.core import kernels
from graytrack.core.estimator.commands import StageCommands, commanded

SHOWN_ACCELERATION = "stage_shown_acceleration_mm_s2"  # model info: the least acceleration the calibration's
# grating readings allow over every four frames (shown_acceleration)
SHOWN_BEYOND = "stage_shown_beyond_commands_mm_s2"  # model info: the same beyond what the stage was commanded to do,
# where the calibration's recording stated its commanded phases
WINDOW = 4  # frames of the test: two before the step, two after (a line's two parameters and the step, one spare)


class Step(NamedTuple):
    """The test's answer: the step (mm), its noise σ (mm), the stage's allowance (mm) and the standardised
    excess of the step over the allowance (> the quantile: the mount's)."""

    step_mm: float
    sigma_mm: float
    allowance_mm: float
    excess: float


def _abs_integral(a: float, b: float, h: float) -> float:
    """∫|linear from a to b| over an interval of length h."""
    if a * b >= 0.0:
        return 0.5 * h * (abs(a) + abs(b))
    return 0.5 * h * (a * a + b * b) / (abs(a) + abs(b))


def _fit(t: np.ndarray, p: np.ndarray, var: np.ndarray, out: np.ndarray) -> bool:
    """The step's fit over four frames into ``out``: (step, its variance, ∫|K|); False where the times do not
    increase, a variance is not positive or the fit has no inverse. Written for numba (kernels.COMPILED)."""
    if not (t[1] > t[0] and t[2] > t[1] and t[3] > t[2]):
        return False
    centre = 0.5 * (t[1] + t[2])
    # the normal matrix of (1, τ, after the step), weighted by 1/var
    n00 = n01 = n02 = n11 = n12 = n22 = 0.0
    for i in range(WINDOW):
        if not var[i] > 0.0:
            return False
        w, tau, h = 1.0 / var[i], t[i] - centre, 1.0 if i >= 2 else 0.0
        n00 += w
        n01 += w * tau
        n02 += w * h
        n11 += w * tau * tau
        n12 += w * tau * h
        n22 += w * h * h
    # the third row of its inverse (cofactors of the symmetric 3 × 3)
    c0 = n01 * n12 - n02 * n11
    c1 = n01 * n02 - n00 * n12
    c2 = n00 * n11 - n01 * n01
    det = n02 * c0 + n12 * c1 + n22 * c2
    if not abs(det) > 0.0:
        return False
    c0, c1, c2 = c0 / det, c1 / det, c2 / det
    step = 0.0
    c = np.empty(WINDOW)  # d = c · p: a functional that every line leaves at zero
    for i in range(WINDOW):
        c[i] = (c0 + c1 * (t[i] - centre) + c2 * (1.0 if i >= 2 else 0.0)) / var[i]
        step += c[i] * p[i]
    # the Peano kernel at the knots, K(t_j) = Σ_i c_i (t_i − t_j)₊ (zero at the first and the last), and ∫|K|
    # over each interval between frames (a stage's acceleration there is bounded interval by interval)
    integral, last = 0.0, 0.0
    for j in range(1, WINDOW):
        knot = 0.0
        for i in range(j + 1, WINDOW):
            knot += c[i] * (t[i] - t[j])
        piece = _abs_integral(last, knot, t[j] - t[j - 1])
        out[2 + j] = piece
        integral += piece
        last = knot
    out[0], out[1], out[2] = step, c2, integral
    # The window's one residual: the speed after the step against the speed before it, q = Σ eᵢ pᵢ, which neither
    # a line nor the step moves. A step the mount made leaves it within the stage's acceleration and the noise;
    # a window that holds a jump at its last frame (the step one frame early) does not.
    before, after = t[1] - t[0], t[3] - t[2]
    c[0], c[1], c[2], c[3] = -1.0 / before, 1.0 / before, 1.0 / after, -1.0 / after
    q, var_q = 0.0, 0.0
    for i in range(WINDOW):
        q += c[i] * p[i]
        var_q += c[i] * c[i] * var[i]
    last = 0.0
    for j in range(1, WINDOW):
        knot = 0.0
        for i in range(j + 1, WINDOW):
            knot += c[i] * (t[i] - t[j])
        out[3 + WINDOW + j] = _abs_integral(last, knot, t[j] - t[j - 1])
        last = knot
    out[2 + WINDOW], out[3 + WINDOW] = q, var_q
    return True


def _pushed(t: np.ndarray, p: np.ndarray, var: np.ndarray, tk: float, pk: float, vk: float,
            out: np.ndarray) -> bool:
    """The newest frame in at the end of the window (the oldest out), then :func:`_fit` of it."""
    for i in range(WINDOW - 1):
        t[i], p[i], var[i] = t[i + 1], p[i + 1], var[i + 1]
    t[WINDOW - 1], p[WINDOW - 1], var[WINDOW - 1] = tk, pk, vk
    return _fit(t, p, var, out)


if kernels.COMPILED:
    _jit = kernels.numba.njit(cache=True, nogil=True, error_model="numpy")
    _abs_integral = _jit(_abs_integral)
    _fit = _jit(_fit)
    _pushed = _jit(_pushed)


OUT = 3 + 2 * WINDOW  # the fit's answer (_fit): the step, its variance, ∫|K|, ∫|K| over each interval
# between frames; the speed's change across the step, its variance, its kernel's ∫|K| over each interval


def _judged(out: np.ndarray, acceleration: np.ndarray | float) -> Step:
    """The step against a stage accelerating at most ``acceleration`` (mm/s²; one for the whole window, or one
    for each interval between its frames)."""
    step, variance, integral = out.item(0), out.item(1), out.item(2)
    sigma = math.sqrt(variance) if variance > 0.0 else 0.0
    allowance = float(np.dot(acceleration, out[3:WINDOW + 2])) if np.ndim(acceleration) else acceleration * integral
    excess = (abs(step) - allowance) / sigma if sigma > 0.0 else (math.inf if abs(step) > allowance else 0.0)
    return Step(step, sigma, allowance, excess)


def step_test(t: np.ndarray, p: np.ndarray, var: np.ndarray, acceleration: np.ndarray | float) -> Step | None:
    """A step between the second and third of four frames (times ``t`` s, positions ``p`` mm, variances
    ``var`` mm²) against a stage accelerating at most ``acceleration`` mm/s² (or that in each of the three intervals
    between them); None where the times do not increase or the fit has no inverse."""
    out = np.empty(OUT)
    if not _fit(np.asarray(t, dtype=np.float64), np.asarray(p, dtype=np.float64),
                np.asarray(var, dtype=np.float64), out):
        return None
    return _judged(out, acceleration)


def shown_acceleration(t: np.ndarray, reading_mm: np.ndarray, phases: np.ndarray | None = None,
                       settle_s: float = 0.0) -> float:
    """The least acceleration (mm/s²) that allows every step the grating's readings make over four frames:
    what the stage itself was seen to do, vibration and the grating's own noise included (a calibration's
    readings: the mount stays where it is, so every step there is the stage's). With the stage's commanded
    ``phases``: what it did beyond what each interval's command allows (:func:`commanded`), the servo's overshoot
    and vibration. 0 with fewer than four readings."""
    t = np.asarray(t, dtype=np.float64)
    reading = np.asarray(reading_mm, dtype=np.float64)
    keep = np.isfinite(t) & np.isfinite(reading)
    t, reading = t[keep], reading[keep]
    ones = np.ones(WINDOW)
    asked = commanded(t, phases, settle_s)
    out = np.empty(OUT)
    shown = 0.0
    for k in range(t.size - WINDOW + 1):
        if not _fit(t[k:k + WINDOW], reading[k:k + WINDOW], ones, out) or not out.item(2) > 0.0:
            continue
        allowed = 0.0 if asked is None else float(np.dot(asked[k:k + WINDOW - 1], out[3:WINDOW + 2]))
        shown = max(shown, (abs(out.item(0)) - allowed) / out.item(2))  # (∫|K|: the step one mm/s² makes)
    return shown


class MountWatch:
    """The last frames' times, carriage positions and variances, and the test of a step among them.

    ``acceleration``: the most the stage accelerates (mm/s²); ``z``: the two-sided quantile of the
    false-alarm rate. :meth:`add` takes a frame the model described (its posterior position); it returns
    the step the mount took, if the test says so, after which the frames it moved are corrected."""

    def __init__(self, acceleration: float, z: float, phases: np.ndarray | None = None, beyond: float = 0.0,
                 settle_s: float = 0.0, commands: StageCommands | None = None):
        self.acceleration, self.z = float(acceleration), float(z)
        # with the commanded phases known, an interval allows what its command asked and what the stage was seen to
        # do beyond its commands (``beyond``, mm/s²), not the stage's most everywhere (``commands``: shared with
        # the motion's process noise, else made of ``phases``)
        self.commands = commands if commands is not None else StageCommands(phases, acceleration, settle_s)
        self.beyond = float(beyond)
        self.t = np.zeros(WINDOW)
        self.p = np.zeros(WINDOW)
        self.var = np.zeros(WINDOW)
        self.n = 0
        self._out = np.empty(OUT)

    def reset(self) -> None:
        self.n = 0

    @property
    def commanded_known(self) -> bool:
        """Whether the stage's commands are known (phases given, even none): between them it holds its speed."""
        return self.commands.known

    def command(self, start: float, end: float, acceleration: float | None = None) -> None:
        """One more commanded phase (:meth:`StageCommands.command`), a phase that ended before the window's oldest
        frame dropped (it reaches no interval again)."""
        self.commands.command(start, end, acceleration, self.t.item(0) if self.n == WINDOW else -math.inf)

    def add(self, t: float, p_mm: float, var_mm2: float) -> Step | None:
        fitted = _pushed(self.t, self.p, self.var, t, p_mm, var_mm2, self._out)  # (one compiled call a frame)
        self.n = min(self.n + 1, WINDOW)
        if self.n < WINDOW or not fitted:
            return None
        out = self._out
        known = self.commands.known
        least = self.beyond if known else self.acceleration
        noise = self.z * math.sqrt(max(out.item(1), 0.0))
        if abs(out.item(0)) - least * out.item(2) <= noise:
            return None  # within the stage's allowance and the step's noise: the frame's, as nearly always
        acceleration = np.full(WINDOW - 1, self.acceleration)
        if known:
            acceleration = np.array([self.beyond + self.commands.asked(self.t.item(j - 1), self.t.item(j))
                                     for j in range(1, WINDOW)])
            if abs(out.item(0)) - float(np.dot(acceleration, out[3:WINDOW + 2])) <= noise:
                return None  # what the stage was commanded to do then makes such a step
        # the same speed before and after the step (within what the stage may do and the noise), else the window
        # holds a change that is not a step between its middle frames: a jump at its last frame is tested next
        turn = abs(out.item(WINDOW + 2)) - float(np.dot(acceleration, out[WINDOW + 4:]))
        if turn > self.z * math.sqrt(max(out.item(WINDOW + 3), 0.0)):
            return None
        step = _judged(out, acceleration)
        self.p[2:] -= step.step_mm  # the carriage's positions, the step now the place's
        return step
