"""How far the trim in force is behind, and by how much it moves per frame: a trim that keeps up.

A trim (core/reference_monitor.py, :class:`~graytrack.core.reference_monitor.Trimmer`) is the line
camera − grating fitted over a window of hundreds of frames. While the rig drifts in time (a lens
warming up slides the image by tens of µm while the stage stands) that line is the window's
average: it lags the drift by the drift rate × half the window, and a 16-row strip whose
magnification drifted 0.15 % over 10 s was placed 1.9-2.3× its bound with 9-11 % of its frames
4+ bounds off the truth, unflagged, and 7-30× through a temperature cycle.

:class:`Follower` watches what is left after the trim: an exponentially weighted straight line
in time of ``camera − grating − trim`` over the last ``memory`` frames. Its value now is how far
the trim is behind (a correction applied on top of the trim once it is beyond its own standard
error), its slope the drift rate, and the frames since its evidence (a frame not fed: a lost or
suspect one) × that rate the lag a position carries in its bound. Pure numerics, O(1) per frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

MEMORY = 20  # frames: the line's time constant (σ of its value now ≈ 2 bounds/√MEMORY)
# the correction is applied once the level is this many of its σ from zero, and dropped below
# CLEAR (hysteresis): a steady run leaves it off, so its positions carry no added noise
APPLY_Z, CLEAR_Z = 3.0, 1.5
BEHIND = 1.0  # a frame is behind when its lag exceeds this many of its own bound


@dataclass(frozen=True)
class Following:
    """The follower's word on one frame, µm: the correction to take off on top of the trim (0 while
    not significant), its standard error (0 with none), and the lag the frame still carries."""

    correction_um: float = 0.0
    sigma_um: float = 0.0
    lag_um: float = 0.0

    def behind(self, bound_mm: float) -> bool:
        """The trim lags this frame by more than :data:`BEHIND` of its bound."""
        return self.lag_um > BEHIND * bound_mm * 1e3


class Hysteresis:
    """:meth:`now` from a follower's ``estimate()``: its value applied once significant beyond
    ``apply_z`` (:data:`APPLY_Z` unless the follower says otherwise), dropped below :data:`CLEAR_Z`."""

    applied: bool = False
    apply_z: float = APPLY_Z

    def estimate(self) -> tuple[float, float, float, float] | None:
        raise NotImplementedError

    def now(self) -> Following:
        """The correction, its σ and the lag, as they stand at this frame."""
        line = self.estimate()
        if line is None:
            return Following()
        value, sigma, lag, z = line
        self.applied = z >= (CLEAR_Z if self.applied else self.apply_z)
        return Following(value, sigma, lag) if self.applied else Following(0.0, 0.0, lag)


@dataclass
class Follower(Hysteresis):
    """Exponentially weighted line ``r(k) = level + rate·(k − now)`` of the residual after the trim."""

    memory: float = MEMORY
    apply_z: float = APPLY_Z
    frame: int = 0  # frames seen (fed or not): the clock the rate is per
    applied: bool = False
    # Σw, Σw·t, Σw·t², Σw·r, Σw·r·t, Σw·r², Σw² (t = k − now; the last counts the frames held: (Σw)²/Σw²)
    _sums: list[float] = field(default_factory=lambda: [0.0] * 7)
    _fed_at: int = -1

    def reset(self) -> None:
        self._sums, self.applied, self._fed_at = [0.0] * 7, False, -1

    def shift(self, change_um: float) -> None:
        """The trim under the residuals moved by ``change_um`` (a new line adopted): the residuals
        kept are restated against it (r → r − change)."""
        s = self._sums
        s[5] += -2.0 * change_um * s[3] + change_um * change_um * s[0]
        s[3] -= change_um * s[0]
        s[4] -= change_um * s[1]

    def tick(self) -> None:
        """One frame passes (fed or not): time moves on, old evidence fades."""
        self.frame += 1
        decay = math.exp(-1.0 / self.memory)
        s = self._sums
        # every t moves one frame further into the past: t → t − 1
        s[2] = decay * (s[2] - 2.0 * s[1] + s[0])
        s[1] = decay * (s[1] - s[0])
        s[4] = decay * (s[4] - s[3])
        s[0] *= decay
        s[3] *= decay
        s[5] *= decay
        s[6] *= decay * decay

    def add(self, residual_um: float, variance_um2: float) -> None:
        """This frame's residual after the trim (at t = 0) with its variance."""
        w = 1.0 / variance_um2
        s = self._sums
        s[0] += w
        s[3] += w * residual_um
        s[5] += w * residual_um * residual_um
        s[6] += w * w
        self._fed_at = self.frame

    def estimate(self) -> tuple[float, float, float, float] | None:
        """The line's value now, its σ, the lag and the level's significance (|level|/σ), whether
        applied or not (None: no line yet)."""
        sw, swt, swtt, swr, swrt, swrr, sww = self._sums
        det = sw * swtt - swt * swt
        if sw <= 0 or det <= 1e-12 * sw * sw:
            return None
        level = (swtt * swr - swt * swrt) / det
        rate = (sw * swrt - swt * swr) / det
        chi2 = max(swrr - level * swr - rate * swrt, 0.0)
        effective = sw * sw / sww
        scatter = max(chi2 / max(effective - 2.0, 1.0), 1.0)  # the residuals' own spread beyond their bounds
        var_level, var_rate = swtt / det * scatter, sw / det * scatter
        age = self.frame - self._fed_at
        return level + rate * age, math.sqrt(var_level + age * age * var_rate), abs(rate) * age, \
            abs(level) / math.sqrt(var_level)
