"""One fast path for every model: each effect the closed loop can add is held by the frame tables,
and the compiled kernel, the tables' numpy evaluation and the model's own ``predict`` agree.

Per effect of the registry: a model grown with it is fitted on a virtual-rig recording whose
images carry a physical cause of that family, and its frames are tracked twice, on the fast path
and with every evaluation done by ``model.predict`` (the direct evaluation): the positions agree to
1e-9 µm. An effect that declares no ``frame_part`` is refused here, not left to a slow path."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from graytrack.core import effects, kernels, small_linalg
from graytrack.core.evaluation import GeneralHarmonics
from graytrack.core.frame_tables import FRAME_PARTS, FrameTables
from graytrack.core.kernels import TableEvaluator
from graytrack.core.tracking import LiveTracker, Tracker, track
from graytrack.drivers.sim.causes import EFFECT_CAUSES, EVERY_FORM
from graytrack.service.grown_models import model_with

MICROMETRE_TOLERANCE = 1e-9
# what a model shows of the table parts that change the expression itself (the others change coefficients)
PART_SEEN = {
    "target map": lambda model: model.target_map is not None,
    "stroke": lambda model: model.stroke_degree > 0,
    "clip": lambda model: model.clip_gray is not None,
    "response": lambda model: model.pixel_gain is not None and model.pixel_offset is not None,
    "mask": lambda model: model.pixel_weight is not None and bool((model.pixel_weight == 0).any()),
}


def test_every_effect_names_its_part_of_the_frame_tables() -> None:
    for name, effect in effects.registry().items():
        assert effect.frame_part in FRAME_PARTS, (
            f"effect {name!r} does not say how tracking holds what it adds (frame_part "
            f"{effect.frame_part!r}; one of {sorted(FRAME_PARTS)}): add it to core/frame_tables.py first")


def test_every_effect_has_a_rig_cause() -> None:
    assert set(EFFECT_CAUSES) == set(effects.registry()), "a new effect needs its cause in drivers/sim/causes.py"


@lru_cache(maxsize=None)
def _fitted(name: str):
    model, run, _ = model_with(name)
    effect = effects.registry()[name.split(":")[0]]
    seen = PART_SEEN.get(effect.frame_part)
    assert seen is None or seen(model), f"{name}: the fitted model does not carry its {effect.frame_part}"
    if name == "target_map:rows":
        assert model.map_rows == model.n_rows > 1, "the variant's model has no map of its own on each row"
    return model, run


def _direct(model, **options) -> Tracker:
    """A tracker whose every evaluation is the model's own predict, on the general moments."""
    tracker = Tracker(model, **options)
    tracker.evaluator = GeneralHarmonics(model)
    tracker.fast_path, tracker.tables = False, None
    return tracker


@pytest.mark.parametrize("name", sorted(EVERY_FORM))  # each effect, and its further forms (a map a row)
def test_kernel_tables_and_predict_agree(name: str) -> None:
    model, run = _fitted(name)
    x_mm = np.linspace(*model.stroke_range_mm, 37)
    expected_values, expected_slopes = model.predict(x_mm, with_derivative=True)
    expected_values = expected_values.reshape(len(x_mm), -1)
    expected_slopes = expected_slopes.reshape(len(x_mm), -1)
    tables = FrameTables.of(model)
    kernel = TableEvaluator(tables)
    one_by_one = [kernel.evaluate(np.array([x])) for x in x_mm]  # the live path: one position a call
    singles = (np.concatenate([v for v, _ in one_by_one]), np.concatenate([s for _, s in one_by_one]))
    for values, slopes in (tables.evaluate(x_mm), kernel.evaluate(x_mm), singles):
        assert np.max(np.abs(values - expected_values)) < 1e-9 * max(1.0, np.abs(expected_values).max())
        assert np.max(np.abs(slopes - expected_slopes)) < 1e-9 * max(1.0, np.abs(expected_slopes).max())
    y = model.prepare(run.frames[:1]).reshape(-1)
    w = np.ones_like(y)
    for x in x_mm[::9]:
        direct = tables.moments(float(x), y, w)
        assert np.allclose(kernel.moments(float(x), y, w), direct, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("name", sorted(EVERY_FORM))  # each effect, and its further forms (a map a row)
def test_the_fast_path_tracks_as_the_direct_evaluation(name: str) -> None:
    model, run = _fitted(name)
    options = {"light": "auto", "robust": True}
    fast = track(model, run, tracker=Tracker(model, **options))
    direct = track(model, run, tracker=_direct(model, **options))
    placed = np.isfinite(direct.x_mm)
    assert placed.mean() > 0.9
    assert np.array_equal(np.isfinite(fast.x_mm), placed)
    assert np.max(np.abs(fast.x_mm[placed] - direct.x_mm[placed])) * 1e3 < MICROMETRE_TOLERANCE
    assert np.allclose(fast.crlb_mm[placed], direct.crlb_mm[placed], rtol=1e-9)


@pytest.mark.parametrize("name", ["target_map", "target_map:rows"])
def test_the_numpy_fallback_gives_the_kernel_numbers(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Without numba (GRAYTRACK_KERNEL=numpy) every evaluation is the tables' numpy one."""
    model, run = _fitted(name)
    compiled = track(model, run, light="auto", robust=True)
    monkeypatch.setattr(kernels, "COMPILED", False)
    fallback = track(model, run, light="auto", robust=True)
    placed = np.isfinite(compiled.x_mm)
    assert np.array_equal(np.isfinite(fallback.x_mm), placed)
    assert np.max(np.abs(compiled.x_mm[placed] - fallback.x_mm[placed])) * 1e3 < MICROMETRE_TOLERANCE


@pytest.mark.parametrize("name", sorted(EVERY_FORM))
def test_live_tracking_reloads_one_buffer_and_tracks_as_the_batch(name: str) -> None:
    """The daemon's frame-at-a-time path (one preallocated batch reloaded per frame, a strip's
    frame or its row mean, for every model whose weights do not follow the signal) gives the batch
    solver's positions, and the positions and verdicts of prepare's route, frame by frame."""
    model, run = _fitted(name)
    batch = track(model, run, x0_mm=float(run.reference[0]), light="auto", robust=True)
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    assert live._lean == (not live.tracker.signal_dependent)
    prepared = LiveTracker(model, x0_mm=float(run.reference[0]))
    prepared._lean = False
    fixes = [live.update(frame, grating) for frame, grating in zip(run.frames, run.reference)]
    again = [prepared.update(frame, grating) for frame, grating in zip(run.frames, run.reference)]
    positions = np.array([fix.x_mm for fix in fixes])
    placed = np.isfinite(positions)
    assert placed.mean() > 0.9 and np.array_equal(np.isfinite([fix.x_mm for fix in again]), placed)
    replayed = np.array([fix.x_mm for fix in again])
    assert np.max(np.abs(positions[placed] - replayed[placed])) * 1e3 < MICROMETRE_TOLERANCE
    assert [(f.locked, f.stale_reason, f.rejected_px, f.transient_px) for f in fixes] == \
        [(f.locked, f.stale_reason, f.rejected_px, f.transient_px) for f in again]
    batch_placed = np.isfinite(batch.x_mm)
    assert np.array_equal(batch_placed, placed)
    assert np.max(np.abs(positions[placed] - batch.x_mm[placed])) * 1e3 < MICROMETRE_TOLERANCE


def test_the_small_solver_gives_numpy_s_answer_and_refuses_a_singular_system() -> None:
    rng = np.random.default_rng(7)
    for size in (2, 3, 4, 6):
        design = rng.normal(size=(3 * size, size))
        normal, projected = design.T @ design, rng.normal(size=size)
        assert np.allclose(small_linalg.solve(normal, projected), np.linalg.solve(normal, projected), rtol=1e-12)
        assert np.allclose(small_linalg.inv(normal), np.linalg.inv(normal), rtol=1e-10, atol=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        small_linalg.solve(np.ones((3, 3)), np.ones(3))


def test_the_focus_sums_compiled_and_in_numpy_agree() -> None:
    """The one pass over the pixels of a focus iteration off the trig tables (core/focus_solve.py)."""
    from graytrack.core import focus_solve

    rng = np.random.default_rng(11)
    values, slopes = rng.normal(size=(3, 300)), rng.normal(size=(3, 300))
    y, w = rng.normal(size=300), rng.uniform(0.0, 2.0, 300)
    w[::7] = 0.0  # masked pixels
    compiled, numpy_sums = np.empty(20), np.empty(20)
    focus_solve._compiled_focus_sums(values, slopes, y, w, 1e-3, compiled)
    focus_solve._focus_sums_numpy(values, slopes, y, w, 1e-3, numpy_sums)
    assert np.allclose(compiled, numpy_sums, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("name", ["target_map", "target_map:rows", "stroke", "rows"])
def test_the_position_kept_gives_a_fresh_evaluation_s_numbers(name: str) -> None:
    """The evaluator keeps the model at the last position (a robust solve reads the residuals at x,
    then solves again from that x): the moments and values read from it are, to the bit, those
    of an evaluator that never saw the frame, and what a caller does to its copies changes nothing."""
    model, run = _fitted(name)
    tables = FrameTables.of(model)
    kept = TableEvaluator(tables)
    y = model.prepare(run.frames[:1]).reshape(-1)
    w = np.linspace(0.5, 1.5, y.size)
    for x in np.linspace(*model.stroke_range_mm, 5):
        values, slopes = kept.evaluate(np.array([x]))
        read = kept.moments(float(x), y, w)
        values[:], slopes[:] = 0.0, 0.0
        again = kept.evaluate(np.array([x]))
        fresh = TableEvaluator(tables)
        assert read == fresh.moments(float(x), y, w)
        fresh_values, fresh_slopes = TableEvaluator(tables).evaluate(np.array([x]))
        assert np.array_equal(again[0], fresh_values) and np.array_equal(again[1], fresh_slopes)
        assert kept.moments(float(x) + 1e-3, y, w) == TableEvaluator(tables).moments(float(x) + 1e-3, y, w)


def test_a_masked_pixel_at_the_sensor_limit_leaves_the_weights_every_frame_shares() -> None:
    """A dead pixel reads the sensor's floor on every frame; masked, it carries no weight anyway.
    Counted as a sample at the limit it had every frame built with weights of its own (the slow
    route, no reloaded batch); a pixel in view at the limit still loses its weight on that frame."""
    model, run = _fitted("bad_pixels")
    model = model.with_changes(info={**model.info, "sensor_range_gray": [0.0, 255.0]})
    tracker = Tracker(model, robust=True)
    masked = tracker.pixel_weight == 0
    frame = np.asarray(run.frames[:1], dtype=np.float64)
    at_limit = (frame.reshape(-1) <= 0.0) | (frame.reshape(-1) >= 255.0)
    assert at_limit[masked].any() and not at_limit[~masked].any()
    weights, shared = tracker.weights(model.prepare(frame), 1)
    assert shared and np.array_equal(weights[0] > 0, ~masked)
    saturated = frame.copy()
    pixel = int(np.flatnonzero(~masked)[0])
    saturated.reshape(-1)[pixel] = 255.0
    weights, shared = tracker.weights(model.prepare(saturated), 1)
    assert not shared and weights[0, pixel] == 0 and (weights[0] > 0).sum() == (~masked).sum() - 1
    live = LiveTracker(model, x0_mm=float(run.reference[0]))
    assert live._lean_batch(run.frames[0], 1) is not None and live._lean_batch(saturated[0], 1) is None
