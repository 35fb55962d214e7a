"""Marks learned on the print from places nothing vouched for (core/texture.py) flag the frames
they correct (core/watches/texture.py): a smudge without a grating.

Without a grating a smudge coming into view pulls the frames (flagged then: the magnification and
focus watches), and its marks are learned at those pulled places, where they then hold the frames
8-13 µm (4-8 bounds) off with χ² at its level. Scored against the truth (the rig's true position),
as bench/robustness_sweep.py does: before, the seed model left 57 of its 500 placed frames (11.4 %)
4+ bounds off unflagged; the marks are now held and the frames they correct flagged ``texture``."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.tracking import track
from graytrack.core.validity import FrameSign
from graytrack.core.watches.texture import TextureWatch
from graytrack.drivers.sim.scenarios import build_rig
from tests.conftest import rig_model

SEED = 3  # the sweep's (seed 4's smudge is placed within its bound by the marks: nothing held pulls it)


@pytest.fixture(scope="module")
def model():
    return rig_model("paper", "", seed=SEED, seconds=20.0)


def test_a_smudge_learned_without_a_grating_holds_no_frame_off_unflagged(model):
    run, truth = build_rig("paper", "smudge:depth=0.35", seed=SEED, run=1).record(10.0)
    result = track(model, run.frames, reference=np.full(run.n_frames, np.nan), light="auto", robust=True,
                   learn=True)
    error = (result.x_mm - truth.x_mm) * 1e3
    period_um = model.period_mm * 1e3
    error -= period_um * np.round(np.nanmedian(error) / period_um)  # no grating: the origin up to whole periods
    placed = np.isfinite(error)
    far = placed & (np.abs(np.where(placed, error, 0.0)) > 4.0 * result.crlb_mm * 1e3)
    # the smudge's frames are off: what this test is about (138 before the shadow's band answered the first
    # frames of a band coming into view, core/moving_band.py, which takes the smudge's for one: 49-50 now)
    assert far.sum() > 40
    assert (far & ~result.stale).sum() <= 0.005 * placed.sum()  # never silently wrong (57 before)
    marks = result.texture["marks"]
    assert len(marks) >= 5 and all(mark["held"] and mark["unvouched"] > 0.1 for mark in marks)
    assert (result.stale_reason[far] == "texture").sum() > 10  # the frames only the marks' flag catches (57; 11)


def test_the_texture_watch_flags_a_placed_frame_the_marks_pulled():
    watch = TextureWatch()
    assert watch.observe(FrameSign(0, pulled=True)) == "texture"
    assert watch.observe(FrameSign(1, pulled=True, placed=False)) is None
    assert watch.observe(FrameSign(2)) is None


def test_a_speck_s_own_shape_vouches_for_it_where_its_frames_did_not(model):
    """Without a grating, while dust lands the running χ² stays suspect and no frame vouches for itself: a
    speck (a dip a pixel wide, coming back up) is not held for it, a piece of a smudge still is
    (core/texture_shape.py; on a 16-row strip every dust mark was held: 337-398 of 500 frames flagged)."""
    from graytrack.core.texture import Texture
    from graytrack.core.texture_mark import Mark

    texture = Texture(model)
    step_px = texture.grid.step_mm / model.pixel_pitch_mm
    nodes = np.arange(-8, 9) * step_px

    def mark(shape: np.ndarray, unvouched: int) -> Mark:
        learned = Mark(-8, nodes.size, model.n_rows, 0, frames=100, unvouched=unvouched)
        learned.applied = np.tile(shape, (model.n_rows, 1))
        return learned

    speck = -0.02 * np.exp(-0.5 * (nodes / 0.4) ** 2)
    smudge = -0.35 * np.exp(-0.5 * ((nodes + 10.0) / (0.7 / 0.062)) ** 2)  # a piece of its flank
    assert not texture._held(mark(speck, 90))
    assert texture._held(mark(smudge, 90))
    assert not texture._held(mark(smudge, 5))  # its frames vouched for it: nothing to hold
