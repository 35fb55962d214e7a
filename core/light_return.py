"""When the tracker takes the calibrated light back after it solved a gain and offset with x.

One rule, kept here for both its users: the tracker applies it frame by frame
(:meth:`~graytrack.core.tracking.Tracker.solve`), and the calibration's adequacy figure
(core/adequacy.py) replays it over the calibration frames, so that what a model is judged on at
calibration is what tracking will do with it.

The light goes back once the calibrated light fits (the χ² freeing it gains is within its 2-dof
noise) on :data:`LIGHT_RETURN_FRAMES` solved frames in a row, not on one: under row banding (an
offset of its own each frame, 1 gray rms) one frame's offset is small by chance every few frames,
and a light taken back on such a frame lets the next frames' offsets move their positions (with
one frame: 1.31x the bound, 8 of 500 frames 4-6 bounds off, nothing flagged: each frame's χ²
within its own limit). A light that jitters fits by chance on one frame in a few, not on ten in
a row; a light that came back costs ten frames a little information.
"""

from __future__ import annotations

import numpy as np

LIGHT_RETURN_CHI2 = 13.8  # χ² (2 dof, 99.9 %) above which the calibrated light (gain 1, offset 0) is refused
LIGHT_RETURN_FRAMES = 10


def after_frame(fitted: int, free_light: bool, excess: float) -> tuple[bool, int]:
    """(the light stays free for the next frame, frames in a row it fitted) after a frame solved
    with a free light or not (``free_light``) whose calibrated light would have cost ``excess``."""
    fitted = fitted + 1 if free_light and excess <= LIGHT_RETURN_CHI2 else 0
    return free_light and fitted < LIGHT_RETURN_FRAMES, fitted


def replay(asks: np.ndarray, excess: np.ndarray) -> np.ndarray:
    """Which of a sequence of frames the tracker solves with a free light, when each frame's χ²
    with the light held asks for it (``asks``) or the frames before left it free; ``excess``: the
    χ² each frame's free light gains."""
    free = np.zeros(asks.shape, dtype=bool)
    held_over, fitted = False, 0
    for k, (asked, gained) in enumerate(zip(asks.tolist(), excess.tolist())):
        free[k] = held_over or asked
        held_over, fitted = after_frame(fitted, bool(free[k]), gained)
    return free
