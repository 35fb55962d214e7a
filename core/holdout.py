"""Which frames a fit does not see: the one rule every held-out figure reads its frames by.

Frames are grouped into blocks of whole runs of one grating reading (:func:`reading_blocks`): frames
of one reading are frames at one position (a stop of a step-and-settle sweep, a slow scan's repeated
readout step), and a held-out frame whose position the fit saw flatters the model. Every other frame
(the even/odd split) is exactly that flattering split on a sweep of stops. :func:`held_out` is the one
fold: every ``HOLDOUT_EVERY``-th block of at least ``HOLDOUT_BLOCK_FRAMES``, fine blocks so that the
held-out frames lie all along the stroke and the recording's time. The closed loop's candidates
(core/diagnosis/heldout.py) and the grating monitor's structure along the stroke
(core/reference_monitor.py) are measured on it.
"""

from __future__ import annotations

import numpy as np

HOLDOUT_BLOCK_FRAMES = 10  # a block: at least this many frames (whole readings)
HOLDOUT_EVERY = 4  # ... of which every this-many-th is held out: three quarters left to fit on


def reading_runs(reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first frame, length) of each run of consecutive frames with one grating reading."""
    reference = np.asarray(reference, dtype=np.float64)
    if reference.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    starts = np.flatnonzero(np.concatenate(([True], reference[1:] != reference[:-1])))
    return starts, np.diff(np.append(starts, reference.size))


def reading_blocks(reference: np.ndarray, least: int) -> np.ndarray:
    """Each frame's block, numbered 0, 1, … in recording order: the runs of one grating reading that
    start within the same ``least`` frames, each run whole. A scan whose every frame has a reading of
    its own gets blocks of ``least`` frames."""
    starts, lengths = reading_runs(reference)
    if starts.size == 0:
        return np.zeros(0, dtype=np.int64)
    _, block = np.unique(starts // max(int(least), 1), return_inverse=True)
    return np.repeat(block, lengths)


def held_out(reference: np.ndarray) -> np.ndarray:
    """The one fold, as a mask over the frames (in recording order): True where a frame is held out."""
    return reading_blocks(reference, HOLDOUT_BLOCK_FRAMES) % HOLDOUT_EVERY == HOLDOUT_EVERY // 2
