"""A learned mark's own shape vouches for it: a speck narrow and whole on its stretch cannot hold a frame
where something pulled it the way a smudge's broad piece does.

Without a grating a mark's evidence is placed at the frames' own positions, and while the running χ² is
suspect nothing vouches for those (core/texture.py holds such a mark: the frames it corrects are flagged).
Two causes keep χ² suspect, and the mark's shape tells them apart:

- dust settling: specks narrower than a pixel to a little wider (σ 0.2–0.6 of a pixel footprint) landing
  one by one; each learned mark is a dip a pixel or so wide at half depth that comes back up on both sides
  (a speck split between two abutting stretches is read across both);
- a smudge coming into view (σ 700 µm, 11 pixel footprints): it is learned in pieces at most 16 px long,
  each as deep at its ends as in its middle; read across its neighbours, its dip is the smudge's, tens of
  pixels wide.

A piece of something broad carries the print's slope across the pixels: learned b off it is a smooth
gradient across the field, which the frame absorbs as a shift (what holds the smudge's frames 4–8 bounds
off with χ² at its level). A whole, narrow speck learned b off instead leaves a dipole a pixel wide that the
corrected sample's variance (its slope times the position's σ, core/texture.py) already counts for little;
and each frame is still checked on its own (the marks moving it beyond 4σ of the nested move is flagged).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from graytrack.core.texture_mark import Mark

NARROW_PX = 2.0  # a speck's dip (its deepest row, above half its depth) is this wide or less


def shape_vouches(mark: Mark, learned: Sequence[Mark], step_px: float) -> bool:
    """The mark's shape is a speck's: in its deepest row, the run of nodes above half the depth around its
    deepest node is at most ``NARROW_PX`` wide and comes back up on both sides. The row is read across the
    learned marks that abut or overlap it (``learned``; a speck split between two stretches is whole again
    there); a dip that runs off the joined stretch is a piece of something broader. Nodes ``step_px`` pixel
    footprints apart. A mark not yet fitted (a candidate: no ``applied``) has no shape to vouch for."""
    if mark.applied is None:
        return False
    values = np.abs(mark.applied)
    r = int(np.argmax(values.max(axis=1)))
    first, last = mark.first, mark.last
    joined = [(mark, mark.applied)] + [(other, other.applied) for other in learned
                                       if other is not mark and other.applied is not None
                                       and other.first <= last + 1 and first - 1 <= other.last]
    first, last = min(m.first for m, _ in joined), max(m.last for m, _ in joined)
    row = np.zeros(last - first + 1)
    for part, applied in joined:  # abutting stretches share their end node: the deeper reading of it
        span = slice(part.first - first, part.last - first + 1)
        row[span] = np.maximum(row[span], np.abs(applied[r]))
    deepest = mark.first - first + int(np.argmax(values[r]))
    if not row[deepest] > 0.0:
        return False
    low = np.flatnonzero(row < 0.5 * row[deepest])
    left, right = low[low < deepest], low[low > deepest]
    if not left.size or not right.size:
        return False  # the dip runs off the stretch: a piece of something broader
    return bool((right[0] - left[-1] - 1) * step_px <= NARROW_PX)
