"""What is left after the trim, followed by the polynomial in time its own recent frames predict best.

The trim's follower (core/trim_follow.py) fits an exponentially weighted straight line in time over
the last 20 frames. A drift that comes and goes (a lens through a temperature cycle: the image
slides ±15 µm over 6 s) curves within that memory, and a line's value now lags a curve by twice its
curvature times the memory squared: a 16-row strip through a 0.15 % cycle was placed 1.5-2.5 µm off
the grating over ~100-frame stretches (4-6 bounds, under a trim σ widened to 1 µm), the run 1.5×
its bound. A quadratic over a shorter memory follows the curve (0.5 µm at most) but is noisier on a
steady drift or a ramp (0.16 µm against the line's 0.12).

:class:`ChosenFollower` runs both and uses, frame by frame, the one whose predictions of the next
frame's residual have erred least over the last :data:`JUDGED` frames (each prediction made
before the frame is added, in units of the frame's variance: the noisier quadratic loses on a
ramp): the evidence, not a setting, says whether the drift curves. Its interface is the line's
(:class:`~graytrack.core.trim_follow.Follower`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from graytrack.core.trim_follow import MEMORY, Following, Hysteresis

CURVED_MEMORY = 10.0  # frames: the quadratic's time constant
JUDGED = 50.0  # frames: the memory of each follower's prediction errors
JUDGED_DECAY = math.exp(-1.0 / JUDGED)


def _shift_rows(size: int) -> list[list[tuple[int, float]]]:
    """Row j: the (i, factor) with Σw·(t−1)^j = Σ factor·Σw·t^i (binomial expansion)."""
    return [[(i, math.comb(j, i) * (-1.0) ** (j - i)) for i in range(j + 1)] for j in range(size)]


def _shifted(sums: list[float], rows: list[list[tuple[int, float]]], decay: float) -> list[float]:
    """The sums one frame on: every t one frame further back, every weight decayed."""
    out = []
    for row in rows:
        total = 0.0
        for i, factor in row:
            total += factor * sums[i]
        out.append(decay * total)
    return out


def _inverse(m: list[list[float]]) -> list[list[float]] | None:
    """The inverse of a symmetric 2×2 or 3×3 matrix (cofactors: numpy's call overhead was most of a
    trimmed frame's cost); None when it is singular beside its own scale."""
    if len(m) == 2:
        (a, b), (_, d) = m
        det = a * d - b * b
        if not abs(det) > 1e-12 * abs(a * d):
            return None
        return [[d / det, -b / det], [-b / det, a / det]]
    (a, b, c), (_, d, e), (_, _, f) = m
    cof = [[d * f - e * e, c * e - b * f, b * e - c * d],
           [0.0, a * f - c * c, b * c - a * e],
           [0.0, 0.0, a * d - b * b]]
    det = a * cof[0][0] + b * cof[0][1] + c * cof[0][2]
    if not abs(det) > 1e-12 * abs(a * d * f):
        return None
    for i in range(3):
        for j in range(i):
            cof[i][j] = cof[j][i]
    return [[value / det for value in row] for row in cof]


@dataclass
class PolyFollower(Hysteresis):
    """Exponentially weighted polynomial ``r(k) = Σ c_j·(k − now)^j`` (``degree`` 1 or 2) of the
    residual after the trim, over the last ``memory`` frames; the interface of the trim's line follower."""

    degree: int = 1
    memory: float = MEMORY
    frame: int = 0  # frames seen (fed or not)
    applied: bool = False
    _fed_at: int = -1

    def __post_init__(self) -> None:
        if self.degree not in (1, 2):
            raise ValueError(f"a follower's polynomial has degree 1 or 2, not {self.degree}")
        self._shift_t = _shift_rows(2 * self.degree + 1)
        self._shift_r = _shift_rows(self.degree + 1)
        self._decay = math.exp(-1.0 / self.memory)
        self.reset()

    def reset(self) -> None:
        # Σw·t^j (j ≤ 2·degree), Σw·r·t^j (j ≤ degree), Σw·r², Σw² (the frames held: (Σw)²/Σw²)
        self._t = [0.0] * (2 * self.degree + 1)
        self._r = [0.0] * (self.degree + 1)
        self._rr = self._ww = 0.0
        self.applied, self._fed_at = False, -1
        # the fit of the sums as they stand
        self._fit: tuple[list[float], list[list[float]]] | Literal[False] | None = None
        self._last: tuple[int, list[float]] | None = None  # the frame of the last fit and its coefficients

    def shift(self, change_um: float) -> None:
        """The trim under the residuals moved by ``change_um``: the residuals kept restated (r → r − change)."""
        self._rr += -2.0 * change_um * self._r[0] + change_um * change_um * self._t[0]
        self._r = [r - change_um * t for r, t in zip(self._r, self._t)]
        self._fit = None

    def tick(self) -> None:
        self.frame += 1
        decay = self._decay
        self._t, self._r = _shifted(self._t, self._shift_t, decay), _shifted(self._r, self._shift_r, decay)
        self._rr *= decay
        self._ww *= decay * decay
        self._fit = None

    def add(self, residual_um: float, variance_um2: float) -> None:
        w = 1.0 / variance_um2
        self._t[0] += w
        self._r[0] += w * residual_um
        self._rr += w * residual_um * residual_um
        self._ww += w * w
        self._fed_at = self.frame
        self._fit = None

    def predict(self, t: float = 0.0) -> tuple[float, float] | None:
        """The polynomial's value at ``t`` frames from now (the frames' clock: t = 0 is the frame that
        has just ticked, the last evidence is ``frame − fed`` frames back) and its variance (None: none yet)."""
        fit = self._fit
        if fit is None:
            fit = self._fit = self._fitted()
        if fit is False:
            return None
        coef, covariance = fit
        if t == 0.0:  # (every frame's question: the value now)
            return coef[0], covariance[0][0]
        g = [float(t) ** j for j in range(self.degree + 1)]
        value = variance = 0.0
        for i, gi in enumerate(g):
            value += coef[i] * gi
            for j, gj in enumerate(g):
                variance += gi * covariance[i][j] * gj
        return value, variance

    def _fitted(self) -> tuple[list[float], list[list[float]]] | Literal[False]:
        """(coefficients, their covariance scaled by the residuals' own scatter), once per frame's state;
        False while the frames held cannot define the polynomial (a line through one, a quadratic through two)."""
        t, r = self._t, self._r
        size = len(r)
        if t[0] <= 0:
            return False
        inverse = _inverse([t[0:2], t[1:3]] if size == 2 else [t[0:3], t[1:4], t[2:5]])
        if inverse is None:
            return False
        coef, explained = [], 0.0
        for row, r_i in zip(inverse, r):
            c = 0.0
            for value, r_j in zip(row, r):
                c += value * r_j
            coef.append(c)
        for c, r_i in zip(coef, r):
            explained += c * r_i
        self._last = (self.frame, coef)
        chi2 = max(self._rr - explained, 0.0)
        effective = t[0] * t[0] / self._ww
        scatter = max(chi2 / max(effective - size, 1.0), 1.0)  # the residuals' own spread beyond their bounds
        if scatter != 1.0:
            inverse = [[value * scatter for value in row] for row in inverse]
        return coef, inverse

    def forecast(self) -> float | None:
        """This frame's value as the last fit foretold it (before this frame's evidence): the frames'
        clock moved on by the frames since, and the sums' decay does not move a fit."""
        if self._last is None:
            return None
        frames, coef = self.frame - self._last[0], self._last[1]
        return sum(c * float(frames) ** j for j, c in enumerate(coef))

    def estimate(self) -> tuple[float, float, float, float] | None:
        """(value now, its σ, the lag, the level's significance), as the line follower's."""
        now, at_fed = self.predict(0.0), self.predict(float(self._fed_at - self.frame))
        if now is None or at_fed is None:
            return None
        sigma = math.sqrt(now[1])
        return now[0], sigma, abs(now[0] - at_fed[0]), abs(now[0]) / sigma


@dataclass
class ChosenFollower:
    """The line and the quadratic side by side; each frame answered by the one that predicted best."""

    members: tuple[PolyFollower, ...] = field(
        default_factory=lambda: (PolyFollower(1, MEMORY), PolyFollower(2, CURVED_MEMORY)))
    chosen: int = 0
    # EW sums of each member's (prediction error)² over the frame's variance
    _errors: list[float] = field(default_factory=lambda: [0.0, 0.0])
    _judged: float = 0.0

    @property
    def frame(self) -> int:
        return self.members[0].frame

    @property
    def applied(self) -> bool:
        return self.members[self.chosen].applied

    def reset(self) -> None:
        for member in self.members:
            member.reset()
        self._errors = [0.0] * len(self.members)
        self._judged, self.chosen = 0.0, 0

    def shift(self, change_um: float) -> None:
        for member in self.members:
            member.shift(change_um)

    def tick(self) -> None:
        for member in self.members:
            member.tick()

    def add(self, residual_um: float, variance_um2: float) -> None:
        errors = [0.0] * len(self.members)
        for i, member in enumerate(self.members):
            predicted = member.forecast()
            errors[i] = math.inf if predicted is None else \
                (residual_um - predicted) ** 2 / variance_um2  # the frame's noise is the same for both
            member.add(residual_um, variance_um2)
        if all(map(math.isfinite, errors)):  # both predicting: each judged on the same frames
            decay = JUDGED_DECAY
            self._errors = [decay * kept + error for kept, error in zip(self._errors, errors)]
            self._judged = decay * self._judged + 1.0
            if self._judged >= JUDGED / 5:
                self.chosen = min(range(len(errors)), key=self._errors.__getitem__)

    def estimate(self) -> tuple[float, float, float, float] | None:
        return self.members[self.chosen].estimate()

    def now(self) -> Following:
        # each member keeps its own hysteresis; the answer is the chosen one's
        answers = [member.now() for member in self.members]
        return answers[self.chosen]
