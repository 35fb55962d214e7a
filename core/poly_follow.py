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

import numpy as np

from graytrack.core.trim_follow import MEMORY, Following, Hysteresis

CURVED_MEMORY = 10.0  # frames: the quadratic's time constant
JUDGED = 50.0  # frames: the memory of each follower's prediction errors


def _shift_matrix(size: int) -> np.ndarray:
    """S with S·[Σw·t⁰, Σw·t¹, …] = [Σw·(t−1)⁰, Σw·(t−1)¹, …] (binomial expansion)."""
    shift = np.zeros((size, size))
    for j in range(size):
        for i in range(j + 1):
            shift[j, i] = math.comb(j, i) * (-1.0) ** (j - i)
    return shift


@dataclass
class PolyFollower(Hysteresis):
    """Exponentially weighted polynomial ``r(k) = Σ c_j·(k − now)^j`` (``degree``) of the residual
    after the trim, over the last ``memory`` frames; the interface of the trim's line follower."""

    degree: int = 1
    memory: float = MEMORY
    frame: int = 0  # frames seen (fed or not)
    applied: bool = False
    _fed_at: int = -1

    def __post_init__(self) -> None:
        self._shift_t = _shift_matrix(2 * self.degree + 1)
        self._shift_r = _shift_matrix(self.degree + 1)
        self.reset()

    def reset(self) -> None:
        # Σw·t^j (j ≤ 2·degree), Σw·r·t^j (j ≤ degree), Σw·r², Σw² (the frames held: (Σw)²/Σw²)
        self._t = np.zeros(2 * self.degree + 1)
        self._r = np.zeros(self.degree + 1)
        self._rr = self._ww = 0.0
        self.applied, self._fed_at = False, -1

    def shift(self, change_um: float) -> None:
        """The trim under the residuals moved by ``change_um``: the residuals kept restated (r → r − change)."""
        self._rr += -2.0 * change_um * self._r[0] + change_um * change_um * self._t[0]
        self._r -= change_um * self._t[: self.degree + 1]

    def tick(self) -> None:
        self.frame += 1
        decay = math.exp(-1.0 / self.memory)
        self._t = decay * (self._shift_t @ self._t)
        self._r = decay * (self._shift_r @ self._r)
        self._rr *= decay
        self._ww *= decay * decay

    def add(self, residual_um: float, variance_um2: float) -> None:
        w = 1.0 / variance_um2
        self._t[0] += w
        self._r[0] += w * residual_um
        self._rr += w * residual_um * residual_um
        self._ww += w * w
        self._fed_at = self.frame

    def predict(self, t: float = 0.0) -> tuple[float, float] | None:
        """The polynomial's value at ``t`` frames from now (the frames' clock: t = 0 is the frame that
        has just ticked, the last evidence is ``frame − fed`` frames back) and its variance (None: none yet)."""
        size = self.degree + 1
        if self._t[0] <= 0:
            return None
        normal = self._t[np.add.outer(np.arange(size), np.arange(size))]
        try:
            inverse = np.linalg.inv(normal)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(inverse)) or np.linalg.cond(normal) > 1e12:
            return None
        coef = inverse @ self._r
        chi2 = max(self._rr - float(coef @ self._r), 0.0)
        effective = self._t[0] * self._t[0] / self._ww
        scatter = max(chi2 / max(effective - size, 1.0), 1.0)  # the residuals' own spread beyond their bounds
        g = float(t) ** np.arange(size)
        return float(coef @ g), float(g @ inverse @ g) * scatter

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
    _errors: np.ndarray = field(default_factory=lambda: np.zeros(2))
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
        self._errors[:] = 0.0
        self._judged, self.chosen = 0.0, 0

    def shift(self, change_um: float) -> None:
        for member in self.members:
            member.shift(change_um)

    def tick(self) -> None:
        for member in self.members:
            member.tick()

    def add(self, residual_um: float, variance_um2: float) -> None:
        errors = np.zeros(len(self.members))
        for i, member in enumerate(self.members):
            predicted = member.predict(0.0) if member._fed_at >= 0 else None
            errors[i] = math.inf if predicted is None else \
                (residual_um - predicted[0]) ** 2 / variance_um2  # the frame's noise is the same for both
            member.add(residual_um, variance_um2)
        if np.all(np.isfinite(errors)):  # both predicting: each judged on the same frames
            decay = math.exp(-1.0 / JUDGED)
            self._errors = decay * self._errors + errors
            self._judged = decay * self._judged + 1.0
            if self._judged >= JUDGED / 5:
                self.chosen = int(np.argmin(self._errors))

    def estimate(self) -> tuple[float, float, float, float] | None:
        return self.members[self.chosen].estimate()

    def now(self) -> Following:
        # each member keeps its own hysteresis; the answer is the chosen one's
        answers = [member.now() for member in self.members]
        return answers[self.chosen]
