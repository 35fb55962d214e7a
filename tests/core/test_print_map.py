"""The print's map in the estimator (core/estimator/print_map.py): what lands on the print is learned at its place
along the target once the motion has carried it across a pixel, and used for the position from then on; what
lands on the sensor's side is never learned into it (and what lands on the print never into the sensor's map:
tests/core/test_sensor_map.py). Scored against the virtual rig's truth, frame by frame, in every mode."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from graytrack.core.estimator import EstimatorSettings
from graytrack.core.estimator.marks import runs
from graytrack.core.estimator.print_map import NODES_PER_PIXEL, PrintMap, apply, locate
from tests.core.test_sensor_map import _scored, _tracked, paper  # noqa: F401  (its rig)


@pytest.mark.parametrize("grating", ["check", "fuse", "none"])
def test_dust_settling_on_the_print_is_learned_where_it_lies(paper, grating):  # noqa: F811
    """Thirty specks land on the print over 8 s. Without the print's map each frame a speck moved into failed at
    new samples (a fifth of the frames flagged with the grating read, five 4+ bounds off; bench/estimator_sweep.py);
    with it the specks are learned as the print carries them across the pixels: few frames flagged, none 4+
    bounds off unflagged, the error within 1.3 noise floors, and the nodes learned darker than calibration and
    at a speck's place on the print (up to the one offset between the rig's target frame and the model's).

    Without the grating too: the run is placed a period off the print's coordinates there (this rig's stroke is
    longer than its period), and the map is read where the run's travel puts it (filter.py _print_at_place). Read
    at the run's own coordinates instead, most of its frames saw the print beyond the map's grid: 24 nodes learned
    where the grating's runs learn 140, the sensor's side holding half the line for the print's dust, 2-5 % of the
    frames flagged, one unplaced and the error 2.4-8.9 µm against 1.7-1.8."""
    estimator, estimates, truth, rig = _tracked(paper, "dust_settling", run=2, grating=grating)
    error, bound, floor, stale = _scored(paper, estimates, truth, grating)
    assert np.all(np.isfinite(error))
    assert not np.any((np.abs(error) > 4 * bound) & ~stale)
    assert stale.mean() <= 0.02, stale.mean()
    if grating != "fuse":  # (fused, the error is the grating's: the floor is the image's)
        assert np.nanstd(error) <= 1.3 * np.sqrt(np.nanmean(floor ** 2)), np.nanstd(error)
    learned = np.flatnonzero(estimator.print_map.learned())
    assert learned.size >= 100, learned.size
    assert estimator.sensor.touched.mean() <= 0.25, estimator.sensor.touched.mean()
    # dust darkens: every mark (a run of neighbouring learned nodes) is darker than calibration. Within one the nodes,
    # each learned from the samples nearest it, may ring about the speck's profile (without the grating a node
    # between two deep ones was read 5-18 % brighter on one node in ten)
    marks = runs(estimator.print_map.learned(), estimator.print_map.stride)
    assert all(estimator.print_map.f[start:stop].mean() < 0.0 for start, stop in marks), marks
    assert not estimator.sensor.learned().any()
    specks = np.array([d.x_mm for d in rig.config.target.defects if d.kind == "dust"])
    widest = max(d.size_mm for d in rig.config.target.defects if d.kind == "dust")
    at = estimator.print_map.place_mm(learned)
    pitch = paper.pixel_pitch_mm
    shifts = np.arange(-30.0, 30.0, pitch / NODES_PER_PIXEL)
    distance = np.array([np.median(np.min(np.abs(at[:, None] + shift - specks[None, :]), axis=1))
                         for shift in shifts])
    shift = shifts[int(np.argmin(distance))]
    near = np.min(np.abs(at[:, None] + shift - specks[None, :]), axis=1)
    reach = 3.0 * widest + EstimatorSettings().map_reach_px * pitch
    assert np.mean(near <= reach) >= 0.95, np.sort(near)[-10:]


@pytest.mark.parametrize("at_rest", [False, True], ids=["moving", "at_rest"])
@pytest.mark.parametrize("grating", ["check", "none"])
def test_dust_on_the_window_is_never_learned_into_the_print(paper, grating, at_rest):  # noqa: F811
    """Specks on the camera's window stay at their pixels as the print moves on: a node they touched is seen clean
    at the next pixel and let go (at rest too, once the stage moves on); none is learned."""
    estimator, estimates, truth, _ = _tracked(paper, "window_dust" + (":at_rest=1" if at_rest else ""), run=2,
                                              grating=grating, at_rest=at_rest)
    error, bound, _, stale = _scored(paper, estimates, truth, grating)
    assert estimator.print_map.landed > 0  # each speck was a candidate on the print too
    assert not estimator.print_map.learned().any(), np.flatnonzero(estimator.print_map.learned())
    assert not np.any((np.abs(error) > 4 * bound) & ~stale)


def _line(n: int = 40) -> tuple[PrintMap, np.ndarray]:
    """A one-row map over 40 pixels of 0.1 mm, its noise 1 gray², and the model's value 100 gray everywhere."""
    target = np.arange(n) * 0.1
    printed = PrintMap(target, 1, n, 0.1 / NODES_PER_PIXEL, -1.0, 8.0, np.array([1.0, 0.0, 0.0]), 1.0, 5.0,
                       np.array([1.0, 1e-8]), 2)
    return printed, np.full(n, 100.0)


def test_a_mark_moving_with_the_print_is_learned_and_one_staying_at_its_pixel_is_let_go():
    """The map's own recursion on a made-up line: a mark 30 % deep at one place on the print, seen as the image
    moves by a tenth of a pixel a frame, is learned there (to its depth within 3σ) and divides out of the
    frames once it has been carried across a pixel; a mark fixed at one pixel while the image moves is let go
    (its nodes' evidence falls below nought) and nothing is learned."""
    rng = np.random.default_rng(1)
    for on_print in (True, False):
        printed, h = _line()
        noise_var, mask = np.ones(h.size), np.ones(h.size)
        mark = 1.3  # target coordinate (mm) of the print's mark, or the pixel of the window's (13)
        for frame in range(60):
            xi = 0.01 * frame
            if on_print:
                depth = -0.3 * np.exp(-0.5 * ((xi + printed.target - mark) / 0.05) ** 2)
            else:
                depth = -0.3 * np.exp(-0.5 * ((np.arange(h.size) - 13.0) / 0.5) ** 2)
            y = h * (1.0 + depth) + rng.normal(0.0, 1.0, h.size)
            if frame == 0:
                core = np.abs(y - h) > 5.0
                assert printed.land(core, 0.0, xi, 0.0) > 0
            y_seen, mask_seen = printed.seen(y, mask, xi, 0.0, 0.0)
            # (no sensor map: the sensor's side's account of each sample is the model's)
            printed.learn(y, h, h, np.zeros(h.size), noise_var, mask, 0.02 * frame)
        learned = np.flatnonzero(printed.learned())
        if on_print:
            assert learned.size >= 2
            at = printed.place_mm(learned)
            assert np.all(np.abs(at - mark) <= 0.15), at
            deepest = learned[np.argmin(printed.f[learned])]
            assert abs(printed.f[deepest] + 0.3) <= 3 * np.sqrt(printed.s[deepest]) + 0.03, printed.f[deepest]
            # the last frame, seen through the map: the samples the mark darkens are the model's within their noise
            # (with the map's) and count again
            darkened = np.abs(y - h) > 10.0
            assert darkened.any() and np.all(mask_seen[darkened] > 0.2), mask_seen[darkened]
            assert np.max(np.abs(y_seen - h)[darkened] * np.sqrt(mask_seen[darkened])) < 3.0
        else:
            assert learned.size == 0
            # every node it touched let go, or holding no mark (one never tested against the mark again may wait)
            assert np.all(np.abs(printed.f[printed.touched]) < 0.05), printed.f[printed.touched]


def test_the_compiled_parts_agree_with_their_definitions():
    """locate: the node nearest each sample's target coordinate and the offset from it; apply: a sample that
    sees an untouched node is the frame's own, one that sees a learned node is divided by 1 + f, f the node's
    carried to the sample by its slope towards the next; one whose node the motion has not decided waits."""
    printed, h = _line(8)
    k, a = np.empty(8, dtype=np.int64), np.empty(8)
    xi = 0.0137
    locate(xi, 0.0, printed.target, printed.centred, printed.rows_of, printed.origin, printed.step, printed.nodes,
           k, a)
    u = (xi + printed.target - printed.origin) / printed.step
    assert np.array_equal(k, np.round(u).astype(np.int64)) and np.allclose(a, u - np.round(u))
    assert np.all(np.abs(a) <= 0.5)
    j = int(k[3])
    printed.touched[[j - 1, j, j + 1]] = True
    printed.f[[j - 1, j, j + 1]] = -0.1, -0.2, -0.4
    printed.lo[[j - 1, j, j + 1]], printed.hi[[j - 1, j, j + 1]] = 0.0, 2.0  # carried across two pixels
    printed.evidence[[j - 1, j, j + 1]] = 100.0  # beyond the sensor's side's account
    y, mask, out, mask_out, fp = np.full(8, 70.0), np.ones(8), np.empty(8), np.empty(8), np.empty(8)
    assert apply(y, mask, k, a, printed.touched, printed.f, printed.s, printed.lo, printed.hi, printed.evidence,
                 printed.confirm, h, printed.noise, 0.0, out, mask_out, fp) == 1
    towards = -0.4 - -0.2 if a[3] >= 0 else -0.2 - -0.1
    expected = -0.2 + towards * a[3]
    assert fp[3] == pytest.approx(expected) and out[3] == pytest.approx(70.0 / (1.0 + expected))
    assert np.array_equal(np.delete(out, 3), np.full(7, 70.0)) and not np.delete(fp, 3).any()
    for undecided in ("travel", "evidence"):
        saved = printed.hi[j], printed.evidence[j]
        if undecided == "travel":
            printed.hi[j] = 0.5  # not yet carried across a pixel
        else:
            printed.evidence[j] = 0.5 * printed.confirm  # not yet beyond the sensor's side's account by the test
        apply(y, mask, k, a, printed.touched, printed.f, printed.s, printed.lo, printed.hi, printed.evidence,
              printed.confirm, h, printed.noise, 0.0, out, mask_out, fp)
        assert mask_out[3] == 0.0 and mask_out[2] == 1.0, undecided
        printed.hi[j], printed.evidence[j] = saved


def test_the_prints_own_marks_are_learned_on_its_calibration_and_a_steady_run_learns_none():
    """A print with three scratches, there at calibration and in the run. The model's smooth series cannot hold a
    scratch; the estimator learned them again in every run (17 nodes read, 18 fused). Calibration now runs the
    estimator over its own sweep with the grating fused and keeps the print's map it learned with the model: a run
    with the grating starts from it and learns nothing but a node or two at a kept mark's edge, placed as well. A
    clean print's calibration keeps none."""
    from graytrack.core.calibration import calibrate
    from graytrack.core.estimator import filter as estimator
    from graytrack.drivers.sim.scenarios import build_rig

    calibration, _ = build_rig("paper", "scratches:count=3", seed=3).record(20.0)
    model = calibrate(calibration, "paper").model
    kept = model.info[estimator.CALIBRATION_PRINT_MAP]
    assert sum(kept["learned"]) >= 5 and kept["marks"], kept["marks"]
    clean, _ = build_rig("paper", "", seed=3).record(20.0)
    assert estimator.CALIBRATION_PRINT_MAP not in calibrate(clean, "paper").model.info
    run, truth = build_rig("paper", "scratches:count=3", seed=3, run=1).record(10.0)
    bare = copy.deepcopy(model)
    bare.info.pop(estimator.CALIBRATION_PRINT_MAP)
    for grating in ("check", "fuse"):
        figures = {}
        for name, tracked in (("kept", model), ("bare", bare)):
            tracker = estimator.Estimator(tracked, settings=EstimatorSettings().for_recording(run.meta),
                                          grating=grating)
            estimates = estimator.track(tracked, run.frames, run.t, run.reference, estimator=tracker)
            error = (np.array([e.x_mm for e in estimates]) - truth.x_mm) * 1e3
            bound = np.array([e.crlb_mm for e in estimates]) * 1e3
            stale = np.array([e.stale for e in estimates])
            printed = tracker.print_map
            fresh = np.flatnonzero(printed.learned() & ~printed.restored)
            # (a node at a scratch's edge that calibration's test left just below may pass the run's: a node of the
            # print's own mark, never one apart from those calibration kept, and a fifth at most of what the run
            # learns without calibration's map)
            apart = [j for j in fresh if not printed.restored[max(j - 2, 0):j + 3].any()]
            figures[name] = (fresh.size, float(np.std(error)), int(np.sum((np.abs(error) > 4 * bound) & ~stale)),
                             len(apart))
        (new, std, silent, apart), (new_bare, std_bare, _, _) = figures["kept"], figures["bare"]
        assert new_bare >= 5 and new <= 0.2 * new_bare and apart == 0, (grating, figures)
        assert std <= 1.05 * std_bare and silent == 0, (grating, figures)


@pytest.mark.parametrize("grating", ["check", "none"])
def test_dust_on_a_strips_print_is_let_go_from_the_sensors_side_as_the_print_carries_it(grating):
    """Dust settling on the print of a 16-row strip: at each sample a speck passes, the sensor's side and the print's
    each hold a candidate until the motion tells them apart. The print's account beats the sensor's pair as the speck
    moves on, and the sample is let go there and then (sensor_map.learn, the rivalry): the sensor's side holds aside
    a tenth of the samples on average over the run, where, let go only once the calibration's account beat the pair,
    it held more than a third, and learned a speck or two of the print as its own."""
    from graytrack.core.calibration import calibrate
    from graytrack.core.estimator import Estimator, track
    from graytrack.drivers.sim.scenarios import build_rig

    calibration, _ = build_rig("strip16", "", seed=1).record(20.0)
    model = calibrate(calibration, "paper").model
    recording, _ = build_rig("strip16", "dust_settling", seed=1, run=1).record(10.0)
    estimator = Estimator(model, grating=grating)
    held = []
    for k in range(recording.n_frames):  # (frame by frame: what the sensor's side holds aside after each)
        track(model, recording.frames[k:k + 1], recording.t[k:k + 1],
              recording.reference[k:k + 1] if grating != "none" else None, estimator=estimator)
        sensor = estimator.sensor
        held.append(np.count_nonzero(sensor.touched & ~sensor.learned()) / sensor.touched.size)
    assert np.mean(held) < 0.2, np.mean(held)
    assert not estimator.sensor.learned().any(), np.flatnonzero(estimator.sensor.learned())
    assert estimator.print_map.learned().sum() >= 50, estimator.print_map.learned().sum()
