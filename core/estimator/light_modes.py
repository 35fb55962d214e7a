"""The light's two modes: holding or drifting, decided from what the frames read of it.

A regulated lamp holds its light for minutes; a camera hunting its gain, a lamp warming or a shadow passing moves
it frame by frame. One rate for both either lets a steady light wander with the noise, and over less than a period
of the print the position with it (a 16-row strip lost a sixth of its precision at the drifting rate), or holds a
light that is moving. So the light's gain and offset have two modes, as filterpy's ``IMMEstimator`` has models: a
*holding* one (``gain_rate_holding``, ``offset_rate_holding``) and a *drifting* one (``gain_rate``,
``offset_rate``), joined by a Markov chain that passes between them at ``light_switch_rate`` per second.

Each frame is predicted in the mode the chain makes likelier for it (the drifting mode's probability carried from
the frames before, moved on by the chain over the interval: :meth:`LightModes.advance`), and updated in it. Then its
reading of the light (the gain and offset the frame alone says, from how far the update moved them against how much
it narrowed them: the prior's and the posterior's marginals) is weighed under both modes' predictions, and the
probability updated by that likelihood ratio (:meth:`LightModes.weigh`). A frame is updated in one mode, not a
mixture: its bound is that mode's posterior. A light that steps is a jump (the frame's test), which a mode does not
replace. The chain starts in the drifting mode: until its frames have found the light, it is as free as a drifting
one.
"""

from __future__ import annotations

import math

import numpy as np

from graytrack.core import kernels


class LightModes:
    """The drifting mode's probability (``probability``) carried from frame to frame; ``drifting``: whether the frame
    being updated is in the drifting mode, ``drifted``: frames predicted in it, in all. ``holding``, ``moving``: the
    (gain, offset) rates' variances per second of the two modes (1/s, gray²/s)."""

    def __init__(self, switch_rate: float, holding: tuple[float, float], moving: tuple[float, float],
                 start: float = 1.0) -> None:
        self.switch_rate = float(switch_rate)
        self.holding, self.moving = holding, moving
        self.start = float(start)
        self.probability = self.start
        self.drifting = self.switch_rate <= 0.0  # (one mode, the drifting one, where the chain never switches)
        self.drifted = 0
        self._before = self.start

    def reset(self) -> None:
        self.probability = self._before = self.start
        self.drifting = self.switch_rate <= 0.0 or self.start > 0.5

    def rates(self) -> tuple[float, float]:
        """The (gain, offset) rates' variances per second the frame is predicted with (its mode's)."""
        return self.moving if self.drifting else self.holding

    def advance(self, dt: float) -> bool:
        """The chain moved on over the interval ``dt`` (s) before a frame: the frame's mode, the likelier one
        (True: drifting)."""
        if self.switch_rate <= 0.0:
            return True
        switch = -math.expm1(-self.switch_rate * max(dt, 0.0))
        self._before = self.probability * (1.0 - switch) + (1.0 - self.probability) * switch
        self.drifting = self._before > 0.5
        self.drifted += self.drifting
        return self.drifting

    def weigh(self, P_prior: np.ndarray, P_post: np.ndarray, s_prior: np.ndarray, s_post: np.ndarray, gain: int,
              offset: int, dt: float) -> None:
        """The frame's reading of the light weighed under both modes, the drifting mode's probability updated.
        ``P_prior``, ``s_prior`` and ``P_post``, ``s_post``: the state's covariance and mean before and after the
        frame's update in its mode, ``gain``, ``offset``: the light's two states in them, ``dt``: the interval (s)."""
        weighing = self.weighing(dt)
        if weighing is not None:
            self.probability = reweigh(P_prior, P_post, s_prior, s_post, gain, offset, *weighing)

    def weighing(self, dt: float) -> tuple[float, float, bool, float] | None:
        """:func:`reweigh`'s numbers for a frame after the interval ``dt`` (s): the drift's variances over it, whether
        the frame is predicted drifting and the chain's probability for it; None where no frame is weighed (no
        interval, or one mode only). (The estimator's update weighs in its own compiled call: kernel.U_LIGHT.)"""
        if dt > 0.0 and self.switch_rate > 0.0:
            return ((self.moving[0] - self.holding[0]) * dt, (self.moving[1] - self.holding[1]) * dt, self.drifting,
                    self._before)
        return None


def reweigh(P_prior: np.ndarray, P_post: np.ndarray, s_prior: np.ndarray, s_post: np.ndarray, gain: int, offset: int,
            eg: float, eo: float, drifting: bool, before: float) -> float:
    """The drifting mode's probability after a frame (:meth:`LightModes.weigh`), from ``before`` (the chain's for
    the frame), the drift's variance over the interval ``eg``, ``eo`` and whether the frame was predicted drifting;
    ``before`` itself where the frame read nothing of the light."""
    a, b, c = P_prior[gain, gain], P_prior[gain, offset], P_prior[offset, offset]
    qa, qb, qc = P_post[gain, gain], P_post[gain, offset], P_post[offset, offset]
    det_p, det_q = a * c - b * b, qa * qc - qb * qb
    if not (det_p > 0.0 and det_q > 0.0):
        return before
    # the frame's own information on the light: the posterior's less the prior's
    ia, ib, ic = qc / det_q - c / det_p, -qb / det_q + b / det_p, qa / det_q - a / det_p
    det_i = ia * ic - ib * ib
    if not (ia > 0.0 and det_i > 0.0):
        return before  # (the frame told the light nothing new)
    # its reading's innovation: z − s⁻ = (P + R) P⁻¹ (s⁺ − s⁻), R = the reading's covariance
    ra, rb, rc = ic / det_i, -ib / det_i, ia / det_i
    m0, m1 = s_post[gain] - s_prior[gain], s_post[offset] - s_prior[offset]
    u0, u1 = (c * m0 - b * m1) / det_p, (-b * m0 + a * m1) / det_p
    sa, sb, sc = a + ra, b + rb, c + rc  # the reading's covariance predicted in the frame's mode
    n0, n1 = sa * u0 + sb * u1, sb * u0 + sc * u1
    if drifting:  # (the holding mode's prediction is narrower by the drift the interval allows)
        cost_hold, cost_drift = _cost(sa - eg, sb, sc - eo, n0, n1), _cost(sa, sb, sc, n0, n1)
    else:
        cost_hold, cost_drift = _cost(sa, sb, sc, n0, n1), _cost(sa + eg, sb, sc + eo, n0, n1)
    if not (math.isfinite(cost_hold) and math.isfinite(cost_drift)):
        return before
    ratio = math.exp(min(max(0.5 * (cost_hold - cost_drift), -50.0), 50.0))  # ℓ(drifting) / ℓ(holding)
    return before * ratio / (before * ratio + 1.0 - before)


def _cost(a: float, b: float, c: float, n0: float, n1: float) -> float:
    """−2 log-likelihood (less its constant) of the innovation (n0, n1) under the covariance ((a, b), (b, c))."""
    det = a * c - b * b
    if not det > 0.0:
        return math.inf
    return (c * n0 * n0 - 2.0 * b * n0 * n1 + a * n1 * n1) / det + math.log(det)


if kernels.COMPILED:
    _jit = kernels.numba.njit(cache=True, nogil=True, error_model="numpy")
    _cost = _jit(_cost)
    reweigh = _jit(reweigh)


__all__ = ["LightModes", "reweigh"]
