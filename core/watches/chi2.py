"""The running χ² against calibration's level: the images have left what the model describes.

χ² says *that* the model no longer fits, not why; while the running χ² is above its own spread
the watch asks each frame's residual which family's shapes it has (core/attribution.py) and names
the family that explains most of it on average. Samples that carry the residual from frame to
frame at the same places are ``pixels``; ones that move (a glint riding on the print, passing
dust) are ``transients``.
"""

from __future__ import annotations

from graytrack.core.attribution import Consistency, named
from graytrack.core.validity import FrameSign, running

WINDOW = 20  # frames over which the shares are averaged
# frames over which the coefficients must hold still: a mimicry's coefficients turn with the
# print's phase and its noise, a light's stay put (a stage at rest cannot tell them apart, and the
# light, the commoner cause, keeps its credit). Longer windows let a slow sweep's mimicry pass.
STILL_WINDOW = 20
# The residual of every this many suspect frames is looked at (it costs an evaluation and a
# projection, ~1 ms on a 16-row strip): a slightly raised χ² can last for most of a run on a real
# rig, and the shares are running averages, which a sample of the frames serves as well.
EXPLAIN_EVERY = 5
# ... at first: a run that stays suspect without going stale is looked at half as often after each
# WINDOW frames learnt, down to one in this many. At 1,000 frames/s a steady χ² a few per cent
# above calibration's (suspect for the whole run, never stale) would otherwise have the daemon's frame
# loop explain 200 frames a second, a third of its time, and drop camera frames; the averages need no
# more than a window of recent looks. Once stale, every EXPLAIN_EVERY-th frame again.
EXPLAIN_EVERY_LONGEST = 80


class ChiSquareWatch:
    family = "geometry"
    reads = ("chi2_suspect", "chi2_stale", "explain")

    def __init__(self) -> None:
        self.shares: dict[str, float] = {}
        self.persistence: float | None = None  # overlap of the largest samples with the last frame's
        self._top: set[int] | None = None
        self._count = 0
        self.consistency: dict[str, Consistency] = {}
        self._interval, self._next, self._learnt = EXPLAIN_EVERY, 1, 0  # the explain cadence (see above)

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.chi2_suspect, sign.chi2_stale, sign.explain)

    def step(self, chi2_suspect: bool, chi2_stale: bool, explain) -> str | None:
        if not chi2_suspect:
            if self._count:  # (what a suspect frame learns comes after its count: at 0 all is reset)
                self._reset()
            return None
        self._count += 1
        backed_off = self._interval > EXPLAIN_EVERY
        if explain is not None and (self._count >= self._next or (chi2_stale and (not self.shares or backed_off))):
            self._learn(explain())
            self._learnt += 1
            if chi2_stale:
                self._interval = EXPLAIN_EVERY
            elif self._learnt % WINDOW == 0:
                self._interval = min(2 * self._interval, EXPLAIN_EVERY_LONGEST)
            self._next = self._count + self._interval
        if not chi2_stale:
            return None
        family = named(self.shares)
        if family == "pixels" and self.persistence is not None and self.persistence < 0.5:
            return "transients"
        return family

    def step_many(self, columns, n: int) -> list[str | None] | None:
        """:meth:`step` of ``n`` frames at once while none is suspect (the common case: nothing to
        learn, a suspect run before forgotten); else None: frame by frame."""
        if columns.array("chi2_suspect", bool).any():
            return None
        if self._count:
            self._reset()
        return [None] * n

    def _reset(self) -> None:
        """A suspect run ended: what it learnt is forgotten and the next one is looked at closely."""
        self.shares, self.persistence, self._top, self._count, self.consistency = {}, None, None, 0, {}
        self._interval, self._next, self._learnt = EXPLAIN_EVERY, 1, 0

    def _learn(self, found: dict) -> None:
        for family, coefficients in found.get("coefficients", {}).items():
            self.consistency.setdefault(family, Consistency(STILL_WINDOW)).add(coefficients)
        for family, share in found.get("shares", {}).items():
            still = self.consistency[family].value if family in self.consistency else 1.0
            self.shares[family] = running(self.shares.get(family), share * still, WINDOW)
        top = found.get("top")
        if top is not None:
            top = set(top)
            if self._top is not None and top:
                overlap = len(top & self._top) / len(top)
                self.persistence = running(self.persistence, overlap, WINDOW)
            self._top = top


def make(tracker) -> ChiSquareWatch:
    return ChiSquareWatch()
