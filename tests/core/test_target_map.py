"""The target map: a row for each model row, fitted, stored and read back; a map the rows shared would be wrong
on each."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.effects.target_map import fit_target_map
from graytrack.core.errors import ModelError
from graytrack.core.models import FourierModel, model_from_dict, model_to_dict

PERIOD_MM, PITCH_MM, PIXELS, ROWS = 8.6, 0.0625, 100, 6


def _strip_model(rows: int = ROWS) -> FourierModel:
    """A calibrated-looking model of ``rows`` rows: a sine of the paper's period, no other structure."""
    model = FourierModel(PERIOD_MM, PITCH_MM, PIXELS, harmonics=1, pixel_degree=0, n_rows=rows, row_shift_mm=0.0)
    coeffs = np.zeros(model.coeff_shape)
    coeffs[0, 0, 0, 0], coeffs[2, 0, 0, 0] = 120.0, 80.0
    return model.with_changes(coeffs=coeffs)


def _spot_on_rows(nodes_mm: np.ndarray) -> np.ndarray:
    """A round dark spot at 3 mm seen by rows 1–2 only, a scratch at 5 mm that drifts by 0.1 mm a row."""
    rows = np.arange(ROWS)[:, None]
    spot = -0.3 * np.exp(-0.5 * ((nodes_mm - 3.0) / 0.05) ** 2) * np.exp(-0.5 * ((rows - 1.5) / 0.7) ** 2)
    scratch = -0.2 * np.exp(-0.5 * ((nodes_mm - 5.0 - 0.1 * rows) / 0.03) ** 2)
    return spot + scratch


def _frames(model: FourierModel, truth: np.ndarray, origin: float, step: float, x_mm: np.ndarray):
    mapped = model.with_changes(coeffs=model.coeffs, target_map=truth, target_map_origin_mm=origin,
                                target_map_step_mm=step)
    smooth = model.predict(x_mm, with_response=False)
    return mapped.predict(x_mm), smooth


def test_a_map_per_row_recovers_what_each_row_sees_where_the_rows_mean_misses() -> None:
    model = _strip_model()
    x_mm = np.linspace(0.0, 4.0, 400)
    step = PITCH_MM / 2
    origin = -step
    nodes = origin + step * np.arange(int((4.0 + PIXELS * PITCH_MM) / step) + 4)
    truth = _spot_on_rows(nodes)
    frames, smooth = _frames(model, truth, origin, step, x_mm)
    weights = np.ones_like(frames)
    per_row = fit_target_map(model, x_mm, frames, smooth, weights)
    mean = _strip_model(rows=1)  # a model of the rows' mean: one map, which the rows then share
    shared = fit_target_map(mean, x_mm, frames.mean(axis=1, keepdims=True), smooth.mean(axis=1, keepdims=True),
                            weights.mean(axis=1, keepdims=True))
    assert per_row["target_map"].shape[0] == ROWS and shared["target_map"].shape[0] == 1
    fitted_per_row = model.with_changes(coeffs=model.coeffs, **per_row)
    fitted_shared = model.with_changes(coeffs=model.coeffs, **shared)
    residual_per_row = frames - fitted_per_row.predict(x_mm)
    residual_shared = frames - fitted_shared.predict(x_mm)
    depth = float(np.abs(frames - smooth).max())
    # the per-row map leaves what the periodic projection takes (the spots' content at the print's
    # own harmonics: a smooth ripple of a few % of the deepest dip); the shared one leaves much of
    # the spot on the rows that see it or miss it
    assert np.abs(residual_per_row).max() < 0.08 * depth
    assert np.abs(residual_shared).max() > 0.4 * depth
    assert np.sqrt(np.mean(residual_per_row**2)) < 0.5 * np.sqrt(np.mean(residual_shared**2))
    # the shared map is the rows' mean: at the spot, rows 1–2 darker than it, the far rows lighter
    at_spot = int(np.argmin(np.abs(nodes - 3.0)))
    shared_value = shared["target_map"][0, int(np.argmin(np.abs(shared["target_map_origin_mm"]
                                                                + step * np.arange(shared["target_map"].shape[1])
                                                                - 3.0)))]
    assert truth[1, at_spot] < shared_value < truth[5, at_spot]


def test_a_per_row_map_is_stored_and_read_back_and_a_wrong_row_count_is_refused() -> None:
    model = _strip_model()
    table = np.random.default_rng(3).normal(0.0, 0.01, (ROWS, 40))
    mapped = model.with_changes(coeffs=model.coeffs, target_map=table, target_map_origin_mm=-0.1,
                                target_map_step_mm=0.03)
    again = model_from_dict(model_to_dict(mapped))
    assert again.map_rows == ROWS and np.array_equal(again.target_map, table)
    x_mm = np.linspace(-0.2, 1.5, 23)
    assert np.array_equal(again.predict(x_mm), mapped.predict(x_mm))
    assert "6 rows × 40" in mapped.describe()
    with pytest.raises(ModelError, match="4 rows; the model has 6"):
        model.with_changes(coeffs=model.coeffs, target_map=table[:4], target_map_step_mm=0.03)
    shared = model.with_changes(coeffs=model.coeffs, target_map=table[0], target_map_step_mm=0.03)
    assert shared.map_rows == 1 and shared.target_map.shape == (1, 40)  # a flat map (older files) is the shared one
