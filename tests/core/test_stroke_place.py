"""Knowledge a calibration keeps place by place along the stroke, read where the frames may be:
without a grating, a model that repeats once a period places its frames only up to whole periods
(core/stroke_place.py), and the local error profile flags a frame wherever a stretch it may be in
erred (core/watches/adequacy.py)."""

from __future__ import annotations


import numpy as np
import pytest

from graytrack.core.stroke_place import folded, in_folded
from graytrack.core.validity import Columns
from graytrack.core.watches.adequacy import LocalAdequacyWatch

EDGES = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
OFF = [True, False, False, False, True]  # the stroke's two ends erred (a scratch at each)


def test_flagged_stretches_fold_onto_one_period_with_their_wrap():
    starts, ends = folded(EDGES, OFF, 3.0)  # [0, 1] stays, [4, 5] folds onto [1, 2]: one interval
    assert starts.tolist() == [0.0] and ends.tolist() == [2.0]
    starts, ends = folded(EDGES, [False, False, True, False, False], 2.5)  # [2, 3] wraps past 2.5
    assert starts.tolist() == [0.0, 2.0] and ends.tolist() == pytest.approx([0.5, 2.5])
    assert folded(EDGES, [False, True, True, True, False], 2.5)[1].tolist() == [2.5]  # wider than a period: all
    inside = in_folded(np.array([0.5, 2.5, 3.5, 4.5, -0.5, np.nan]), 0.0, 3.0, *folded(EDGES, OFF, 3.0))
    assert inside.tolist() == [True, False, True, True, False, False]


def test_without_a_grating_a_repeating_models_frame_is_flagged_where_it_may_be():
    """A frame the tracker placed at 3.5 mm may be at 0.5 mm (a period of 3 mm away), which erred at
    calibration: flagged until a grating reading places the run; with the grating, only where it is."""
    watch = LocalAdequacyWatch(EDGES, OFF, period_mm=3.0)
    unread = [watch.step(True, x) for x in (2.5, 3.5, 1.5)]
    assert unread == [None, "geometry", "geometry"]  # 2.5: nowhere off; 3.5 ~ 0.5; 1.5 ~ 4.5
    assert watch.step(True, 3.5, 3.5) is None  # read: the frame is at 3.5, which calibrated at its bound
    assert watch.step(True, 1.5) is None and watch.step(True, 4.5) == "geometry"  # the place stays known
    placed = LocalAdequacyWatch(EDGES, OFF)  # a model that does not repeat: placed by its image
    assert [placed.step(True, x) for x in (2.5, 3.5, 1.5, 4.5)] == [None, None, None, "geometry"]


def test_many_frames_at_once_as_frame_by_frame():
    rng = np.random.default_rng(5)
    n = 400
    x = rng.uniform(-1.0, 6.0, n)
    reference = np.where(np.arange(n) >= 250, x, np.nan)  # the grating read from frame 250 on
    reference[300:310] = np.nan  # ... with a gap: the place stays known
    placed = rng.random(n) > 0.05
    stepped = LocalAdequacyWatch(EDGES, OFF, period_mm=3.0)
    expected = [stepped.step(p, xi, r) for p, xi, r in zip(placed, x, reference)]
    at_once = LocalAdequacyWatch(EDGES, OFF, period_mm=3.0)
    families = []
    for start, stop in ((0, 100), (100, 101), (101, n)):
        part = Columns(x_mm=x[start:stop].tolist(), placed=placed[start:stop].tolist(),
                       reference_mm=reference[start:stop].tolist())
        families += at_once.step_many(part, stop - start)
    assert families == expected and at_once.place.known and stepped.place.known
    assert expected[:250].count("geometry") > expected[250:].count("geometry") * 250 / 150 * 1.2


def test_the_seed_model_without_a_grating_flags_the_scratches_stretches_where_the_frames_truly_are():
    """The paper rig with 3 scratches, the seed model (which repeats every 8.6 mm over a 10.45 mm
    stroke), tracked without its grating: the run starts a period from the stage, and the frames
    at the start, where the calibration erred 2.5-3.7× its bound, were read against a stretch at
    its bound and went unflagged, 4-6 bounds off the truth (5 of 8 far frames, 1.00 % of the run)."""
    from graytrack.core.calibration import calibrate
    from graytrack.core.tracking import track
    from graytrack.core.watches.adequacy import LOCAL_LIMIT
    from graytrack.drivers.sim.scenarios import build_rig

    calibration, _ = build_rig("paper", "scratches:count=3", seed=3).record(20.0)
    run, truth = build_rig("paper", "scratches:count=3", seed=3, run=1).record(4.0)
    model = calibrate(calibration, "paper").model
    unread = np.full(run.n_frames, np.nan)
    result = track(model, run.frames, reference=unread, light="auto", robust=True)
    error = (result.x_mm - truth.x_mm) * 1e3
    period_um = model.period_mm * 1e3
    whole = period_um * np.round(np.nanmedian(error) / period_um)
    assert whole != 0  # the run placed a period from the stage (the origin's guess)
    profile = model.info["calibration_error_profile"]
    edges, ratio = np.array(profile["edges_mm"]), np.array(profile["ratio"])
    stretch = np.clip(np.searchsorted(edges, truth.x_mm, side="right") - 1, 0, ratio.size - 1)
    off = (ratio[stretch] > LOCAL_LIMIT) & (truth.x_mm <= edges[-1])
    assert off.sum() >= 20
    assert result.stale[off].all()  # where the stage truly was, the calibration erred: flagged
    far = np.abs(error - whole) > 4.0 * result.crlb_mm * 1e3
    assert far.sum() >= 2 and not (far & ~result.stale).any()
