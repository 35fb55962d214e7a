"""A learned mark's shape vouches for it (core/texture_shape.py): a speck's dip, narrow and coming back up
(read across the learned marks abutting it), against a smudge learned in pieces at most 16 px long.

The shapes are the rig's own (drivers/sim `dust_settling`: σ 0.2–0.6 of a pixel footprint; `smudge`: σ 700 µm,
11 footprints of the paper rig's 62 µm) on the texture grid (nodes a quarter of a footprint apart, 16 rows),
with the fit's noise on them (seeded)."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.texture_mark import Mark
from graytrack.core.texture_shape import shape_vouches

STEP_PX = 0.25
ROWS = 16


def _marks(sigma_px: float, depth: float, cuts_px: list[float], seed: int = 0, noise: float = 0.0005) -> list[Mark]:
    """A Gaussian dip centred at 0 learned as abutting marks on the nodes between ``cuts_px``, every row,
    with the fit's noise on each node (σ ``noise``: the learned specks' 0.0001–0.0006, the smudge's
    0.0006–0.0013)."""
    rng = np.random.default_rng(seed)
    marks = []
    for start, stop in zip(cuts_px[:-1], cuts_px[1:]):
        first, last = round(start / STEP_PX), round(stop / STEP_PX) - 1
        nodes = np.arange(first, last + 1) * STEP_PX
        mark = Mark(first, last - first + 1, ROWS, 0)
        mark.applied = -depth * np.exp(-0.5 * (nodes / sigma_px) ** 2)[None, :] + rng.normal(
            0.0, noise, (ROWS, nodes.size))
        marks.append(mark)
    return marks


@pytest.mark.parametrize("sigma_px", [0.2, 0.4, 0.6])
def test_a_speck_narrower_than_a_pixel_or_a_little_wider_vouches_for_itself(sigma_px):
    for seed in range(5):
        whole = _marks(sigma_px, 0.02, [-2.0, 2.25], seed)
        assert shape_vouches(whole[0], whole, STEP_PX)
        split = _marks(sigma_px, 0.02, [-2.0, 0.0, 2.25], seed)  # split between two stretches, read across both
        assert all(shape_vouches(mark, split, STEP_PX) for mark in split)
        assert not shape_vouches(split[1], split[1:], STEP_PX)  # its other half not learned yet: held meanwhile


def test_no_piece_of_a_smudge_does():
    sigma_px = 0.7 / 0.062
    for seed in range(5):
        pieces = _marks(sigma_px, 0.35, list(np.arange(-27.5, 27.6, 5.5)), seed, noise=0.0013)  # as learned: ±2.4σ
        assert not any(shape_vouches(mark, pieces, STEP_PX) for mark in pieces)
        assert not any(shape_vouches(mark, [mark], STEP_PX) for mark in pieces)


def test_a_dip_wider_than_two_pixels_does_not():
    wide = _marks(1.5, 0.05, [-6.0, 6.0])  # whole, but 3.5 px wide at half depth
    assert not shape_vouches(wide[0], wide, STEP_PX)
    flat = _marks(0.4, 0.0, [-2.0, 2.0])
    flat[0].applied[:] = 0.0  # nothing learned
    assert not shape_vouches(flat[0], flat, STEP_PX)
