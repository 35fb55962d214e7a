"""When a change that came and went has left: the running χ² forgets it.

The tracker's running χ² (over about a hundred frames, core/tracking.py) is what frees the light
and what the stale flags read: a change too small for one frame to show builds up in it. An
episode that comes and goes (a cable's shadow sweeping across the field for a second) lifts it
too, and an exponential average remembers the episode for several of its windows after the
images fit again: on the paper rig, a 45-frame shadow kept the light solved and the model flagged
stale (``light``, then ``geometry``, ``transients``: the χ² watch reading residuals at the
calibration's level) for 300 frames more, three times the frames the shadow covered.

An episode has ended when the last :data:`RECENT` frames' χ² mean is at the calibration's level
(within five of its own spreads) *and* beyond five of those spreads below the running average:
the average is then held up by frames that no longer describe the images, and is restarted from
the recent frames (as a plain mean of that many frames, as at the start of a run). A change that
persists keeps the recent frames up with the average, and is never forgotten this way; nor is one
that a light field describes (a lamp's new vignetting): a frame whose answer needed one counts as
not fitting, so only frames the calibrated model describes with a uniform light (and a focus term,
whose frames the running χ² reads at the calibration's focus) end an episode.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

RECENT = 10  # frames: the light goes back to calibration's after as many (core/light_return.py)


@dataclass
class RecentChi2:
    """The last :data:`RECENT` frames' χ² (each capped as the running average caps it; infinite for
    a frame whose answer needed a light field)."""

    values: deque = field(default_factory=lambda: deque(maxlen=RECENT))

    def add(self, chi2: float, plain: bool = True) -> None:
        self.values.append(chi2 if plain else math.inf)

    def ended(self, running: float, calibration: float, limits: list[float]) -> float | None:
        """The recent frames' mean when the episode that holds ``running`` up has ended (None: it
        has not). ``limits``: the sustained χ² limit by the number of frames averaged (from 1)."""
        margin = limits[RECENT - 1] - calibration  # five spreads of a RECENT-frame mean
        if running - calibration <= margin or len(self.values) < RECENT:
            return None  # (the common case, one comparison a frame: nothing holds the average up)
        recent = sum(self.values) / RECENT
        return recent if recent <= limits[RECENT - 1] and running - recent > margin else None

