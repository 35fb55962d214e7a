"""A learned mark's shape vouches for it (core/texture_shape.py): a speck's dip, narrow and coming back up
inside its stretch, against a piece of a smudge learned in 16-px pieces (as deep at its ends as inside).

The shapes are the rig's own (drivers/sim `dust_settling`: σ 0.2–0.6 of a pixel footprint; `smudge`: σ 700 µm,
11 footprints of the paper rig's 62 µm) on the texture grid (nodes a quarter of a footprint apart, 16 rows),
with the fit's noise on them (seeded)."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.texture_shape import shape_vouches

STEP_PX = 0.25
ROWS = 16


def _mark(sigma_px: float, depth: float, from_px: float, to_px: float, seed: int = 0) -> np.ndarray:
    """A Gaussian dip centred at 0, sampled on nodes ``from_px..to_px``, every row, with noise at 3 % of its depth."""
    nodes = np.arange(from_px, to_px + 1e-9, STEP_PX)
    shape = -depth * np.exp(-0.5 * (nodes / sigma_px) ** 2)
    noise = np.random.default_rng(seed).normal(0.0, 0.03 * depth, (ROWS, nodes.size))
    return shape[None, :] + noise


@pytest.mark.parametrize("sigma_px", [0.2, 0.4, 0.6])
def test_a_speck_narrower_than_a_pixel_or_a_little_wider_vouches_for_itself(sigma_px):
    for seed in range(5):
        assert shape_vouches(_mark(sigma_px, 0.02, -2.0, 2.25, seed), STEP_PX)
        assert shape_vouches(_mark(sigma_px, 0.02, -0.75, 3.5, seed), STEP_PX)  # a neighbour's mark abuts its left


@pytest.mark.parametrize("piece", [(-16.0, -10.5), (-5.5, 0.0), (-2.75, 2.75), (10.0, 15.5), (-16.0, 0.0)])
def test_a_piece_of_a_smudge_does_not(piece):
    sigma_px = 0.7 / 0.062
    for seed in range(5):
        assert not shape_vouches(_mark(sigma_px, 0.35, *piece, seed), STEP_PX)


def test_a_dip_wider_than_two_pixels_or_cut_by_its_stretch_does_not():
    assert not shape_vouches(_mark(1.5, 0.05, -6.0, 6.0), STEP_PX)  # whole, but 3.5 px wide at half depth
    assert not shape_vouches(_mark(0.4, 0.02, 0.0, 4.0), STEP_PX)  # its deepest node on the stretch's end
    assert not shape_vouches(np.zeros((ROWS, 17)), STEP_PX)  # nothing learned
