"""The transients watch: glints and passing dust are set aside frame by frame, until they stop being rare.

One glint costs its frame a few samples and is no reason to distrust the model: the robust solve
sets it aside (``FrameSolution.transient_px``) and the frame's bound grows by what it lost. But
when most frames need it (a window letting the sun in, a fibre fluttering over the target) the
images are no longer the calibrated ones plus a rare blob, and every frame rests on fewer samples
than the bound of a clean frame promises elsewhere: the model is stale, with ``transients`` as the
reason.

A blob that keeps to the same pixels frame after frame is no transient: it is fixed to the
camera, stray light in the lens or a window (a glare; a cluster of bad pixels would have shown at
calibration). So this watch also follows where the blobs sit (``FrameSign.transient_at``): blobs
that wander are ``transients``, blobs that stay put are ``light``. (The robust solve sets most of
such a glare aside, which is what keeps the error within a few bounds, and is also why the
residual's shape no longer shows it as light.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from graytrack.core.validity import FrameSign, running

WINDOW = 100  # frames the share of frames with a transient is averaged over
SHARE_STALE = 0.5  # most frames need a blob set aside: not rare any more
SHARE_CLEAR = 0.25  # and the flag clears only well below that (no flicker of the flag at the edge)
FIXED_SPREAD_PX = 5.0  # blobs whose place scatters less than this (rms, pixels) stay put: not transients


@dataclass
class TransientWatch:
    family: str = "transients"
    share: float | None = None  # running share of frames with samples set aside as a transient
    place: float | None = None  # running mean of where the blobs sit (pixel) …
    place_sq: float | None = None  # … and of its square: their spread
    blamed: str | None = None  # the family blamed now
    reads = ("placed", "transient_px", "transient_at", "frame")  # (a class attribute: not a field)

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.placed, sign.transient_px, sign.transient_at, sign.frame)

    def step(self, placed: bool, transient_px: int, at: float, frame: int) -> str | None:
        if not placed and transient_px == 0:
            return self.blamed
        self.share = running(self.share, 1.0 if transient_px > 0 else 0.0, WINDOW)
        if transient_px > 0 and math.isfinite(at):
            self.place = running(self.place, at, WINDOW)
            self.place_sq = running(self.place_sq, at * at, WINDOW)
        if frame >= WINDOW // 4:
            frequent = self.share > SHARE_STALE or (self.blamed is not None and self.share > SHARE_CLEAR)
            self.blamed = None if not frequent else (self.family if self.wandering else "light")
        return self.blamed

    @property
    def wandering(self) -> bool:
        """The blobs do not keep to the same pixels (unknown places count as wandering)."""
        if self.place is None or self.place_sq is None:
            return True
        return math.sqrt(max(self.place_sq - self.place * self.place, 0.0)) > FIXED_SPREAD_PX

    def step_many(self, columns, n: int) -> list[str | None] | None:
        """:meth:`step` of ``n`` frames at once (compiled: core/watches/_kernels.py)."""
        import numpy as np

        from graytrack.core.watches import _kernels

        if not _kernels.COMPILED:
            return None
        codes = {None: 0, self.family: 1, "light": 2}
        state = np.array([self.share or 0.0, self.place or 0.0, self.place_sq or 0.0, self.share is not None,
                          self.place is not None, self.place_sq is not None, codes[self.blamed]], dtype=np.float64)
        out = np.zeros(n, dtype=np.int64)
        _kernels._transient_run(state, columns.array("placed", bool), columns.array("transient_px", np.int64),
                                columns.array("transient_at", np.float64), columns.array("frame", np.int64), WINDOW,
                                WINDOW // 4, SHARE_STALE, SHARE_CLEAR, FIXED_SPREAD_PX, out)
        values = state.tolist()
        self.share = values[0] if values[3] else None
        self.place = values[1] if values[4] else None
        self.place_sq = values[2] if values[5] else None
        names = (None, self.family, "light")
        self.blamed = names[int(values[6])]
        if not out.any():
            return [None] * n
        return np.array(names, dtype=object)[out].tolist()


def make(tracker) -> TransientWatch | None:
    """Only a robust tracker sets transients aside (a plain one has none to count)."""
    return TransientWatch() if getattr(tracker, "robust", False) else None
