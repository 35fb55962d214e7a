"""Held-out figures are the instrument's: the worse of plain and robust tracking.

A per-row model whose target map the rows share (the map of the rows' mean) holds the dust only in
part: tracked plainly the misfit averages out; tracked robustly, as the instrument tracks, the
spot's samples are set aside and the map's dip on the other rows pulls the position. The closed
loop must judge a model by the error the instrument will have."""

from __future__ import annotations

import numpy as np

from graytrack.core.calibration_data import calibration_data
from graytrack.core.diagnosis.heldout import figures, track_runs
from graytrack.service.grown_models import model_with


def _spread(tracked, data) -> float:
    error = tracked.error_um(data.x_mm)
    return float(np.std(error[np.isfinite(error)]))


def test_a_map_the_rows_share_is_judged_by_its_robust_error() -> None:
    model, run, _ = model_with("target_map:rows")
    assert model.map_rows == model.n_rows == 16
    shared = model.with_changes(coeffs=model.coeffs, target_map=model.target_map.mean(axis=0, keepdims=True))
    data = calibration_data(run)
    plain, robust = (_spread(track_runs(shared, data, robust), data) for robust in (False, True))
    assert robust > 1.3 * plain  # the robust solve's bias on a map that is wrong on every row
    assert figures(shared, data).error_std_um == robust
    own_plain, own_robust = (_spread(track_runs(model, data, robust), data) for robust in (False, True))
    assert figures(model, data).error_std_um == max(own_plain, own_robust)
