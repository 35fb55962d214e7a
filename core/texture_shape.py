"""A learned mark's own shape vouches for it: a speck narrow and whole on its stretch cannot hold a frame
where something pulled it the way a smudge's broad piece does.

Without a grating a mark's evidence is placed at the frames' own positions, and while the running χ² is
suspect nothing vouches for those (core/texture.py holds such a mark: the frames it corrects are flagged).
Two causes keep χ² suspect, and the mark's shape tells them apart:

- dust settling: specks narrower than a pixel to a little wider (σ 0.2–0.6 of a pixel footprint) landing
  one by one; each learned mark is a dip a pixel or so wide at half depth, back near 0 at both ends of
  its stretch (measured on the 16-row strip without a grating: half-depth widths 0.75–1.5 px on 12 of 15
  marks, the ends within 0.01–0.14 of the depth on most);
- a smudge coming into view (σ 700 µm, 11 pixel footprints): it is learned in pieces at most 16 px long,
  each as deep at its ends as in its middle (end/depth 0.99–1.0 on all 10 pieces, half-depth 2.25–6 px).

A piece of something broad carries the print's slope across the pixels: learned b off it is a smooth
gradient across the field, which the frame absorbs as a shift (what holds the smudge's frames 4–8 bounds
off with χ² at its level). A whole, narrow speck learned b off instead leaves a dipole a pixel wide that the
corrected sample's variance (its slope times the position's σ, core/texture.py) already counts for little;
and each frame is still checked on its own (the marks moving it beyond 4σ of the nested move is flagged).
"""

from __future__ import annotations

import numpy as np

NARROW_PX = 2.0  # a speck's dip (its deepest row, above half its depth) is this wide or less


def shape_vouches(values: np.ndarray, step_px: float) -> bool:
    """The mark's shape ``values`` (rows × nodes, relative reflectance, nodes ``step_px`` pixel footprints
    apart) is a speck's: in its deepest row, the run of nodes above half the depth around the deepest node
    is at most ``NARROW_PX`` wide and ends inside the stretch on both sides (a dip that comes back up; a
    neighbouring speck's mark may abut it, a broad thing's piece never comes back up within its stretch)."""
    depth = np.abs(values)
    row = depth[int(np.argmax(depth.max(axis=1)))]
    deepest = int(np.argmax(row))
    if not row[deepest] > 0.0:
        return False
    low = np.flatnonzero(row < 0.5 * row[deepest])
    left, right = low[low < deepest], low[low > deepest]
    if not left.size or not right.size:
        return False  # the dip runs off the stretch: a piece of something broader
    return bool((right[0] - left[-1] - 1) * step_px <= NARROW_PX)
