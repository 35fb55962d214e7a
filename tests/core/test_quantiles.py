"""The tests' thresholds: the normal and χ² upper quantiles the estimator sets at its false-alarm rate, held to
scipy's (which the estimator no longer imports: a second a process)."""

import subprocess
import sys

import pytest
from scipy.stats import chi2, norm

from graytrack.core.quantiles import chi2_isf, chi2_sf, normal_isf

pytestmark = pytest.mark.unit

PROBABILITIES = (0.5, 0.1, 1e-2, 1e-4, 1e-6, 1e-9, 1e-12)


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5, 6, 7, 10])
def test_the_chi2_quantiles_and_survival_match_scipys(k: int) -> None:
    for p in PROBABILITIES:
        assert chi2_isf(p, k) == pytest.approx(chi2.isf(p, k), rel=1e-10)
        x = chi2.isf(p, k)
        assert chi2_sf(x, k) == pytest.approx(p, rel=1e-9)


def test_the_normal_quantile_matches_scipys_deep_in_the_tail() -> None:
    for p in PROBABILITIES + (0.9, 1e-15):
        assert normal_isf(p) == pytest.approx(norm.isf(p), rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("bad", [0.0, 1.0, -0.1, 1.5, float("nan")])
def test_a_probability_outside_the_open_unit_interval_is_refused(bad: float) -> None:
    for call in (lambda: normal_isf(bad), lambda: chi2_isf(bad, 2)):
        with pytest.raises(ValueError, match="tail probability"):
            call()
    with pytest.raises(ValueError, match="degrees of freedom"):
        chi2_sf(1.0, 0)


def test_the_estimator_is_made_without_importing_scipy_stats() -> None:
    script = ("import sys, numpy as np\n"
              "from graytrack.core.estimator.filter import Estimator\n"
              "from graytrack.drivers.sim.scenarios import build_rig\n"
              "from graytrack.core.calibration import calibrate\n"
              "cal, _ = build_rig('paper', '', seed=1).record(2.0)\n"
              "model = calibrate(cal, 'paper').model\n"
              "Estimator(model)\n"
              "print('scipy.stats' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "False"
