"""The closed loop's judgement of an effect on held-out figures (core/diagnosis/loop.py ``_better``): kept
when the residual drops beyond its sampling noise without costing the error, rejected otherwise, and
rejected with a reason (never a crash) when the held-out frames have no scatter to judge against."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.diagnosis.heldout import Figures
from graytrack.core.diagnosis.loop import _better

pytestmark = pytest.mark.unit


def _figures(rmse_gray: float, errors_um: list[float]) -> Figures:
    error = np.asarray(errors_um, dtype=float)
    return Figures(model="m", rmse_gray=rmse_gray, error_std_um=float(np.nanstd(error)),
                   error_max_um=float(np.nanmax(np.abs(error))), error_mean_um=float(np.nanmean(error)), crlb_um=1.0,
                   error_um=error, x_mm=np.zeros(error.size), tracked=None)  # type: ignore[arg-type]


def test_a_residual_halved_at_the_same_error_is_kept_and_a_worse_one_rejected():
    rng = np.random.default_rng(1)
    errors = rng.normal(0.0, 1.0, 300).tolist()
    old = _figures(2.0, errors)
    assert _better(_figures(1.0, errors), old, 30_000)[0]
    kept, why = _better(_figures(2.1, errors), old, 30_000)
    assert not kept and why.startswith("rejected: held-out rmse 2.000 → 2.100 gray")


@pytest.mark.parametrize("errors", [[0.3], [0.3, 0.3, 0.3], [np.nan, 0.2]])
def test_held_out_figures_without_scatter_reject_with_their_reason(errors):
    """One placed held-out frame (a 16-row glare strip's loop raised ZeroDivisionError here)."""
    kept, why = _better(_figures(1.0, errors), _figures(2.0, errors), 30_000)
    assert not kept and "cannot judge" in why and "placed frames" in why
