"""The photon-transfer curve estimated from calibration data, and what calibration does with it."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.models.io import model_from_dict, model_to_dict
from graytrack.core.noise import crlb_mm, estimate_pixel_noise
from graytrack.drivers.sim.scenarios import build_rig

# 10 ke⁻ full well, 30 e⁻ read noise, 8 bit: K = 255/10000 gray/e⁻, read variance (30·K)² = 0.585 gray².
SENSOR = "photon_transfer:full_well=10000:read_e=30:bits=8:black_gray=0,rows:n=8"
READ_VAR, SHOT_GAIN = (30 * 255 / 10000) ** 2, 255 / 10000


@pytest.fixture(scope="module")
def shot_noise_recording():
    recording, _ = build_rig("paper", SENSOR, seed=5).record(6.0)
    return recording


def test_curve_from_a_moving_sweep_matches_the_sensor(shot_noise_recording):
    rec = shot_noise_recording
    noise = estimate_pixel_noise(rec.strip(), rec.reference, rec.meta["period_mm"], rec.meta["bit_depth"])
    assert noise.signal_dependent
    assert noise.shot_gain == pytest.approx(SHOT_GAIN, rel=0.08)
    assert noise.read_var == pytest.approx(READ_VAR, rel=0.15)
    assert noise.quant_var == pytest.approx(1 / 12)


def test_calibration_weights_by_the_curve_and_its_chi2_is_one(shot_noise_recording):
    model = calibrate(shot_noise_recording, "paper").model
    assert model.pixel_noise is not None and model.pixel_noise.signal_dependent
    # residuals normalised by the curve are unit variance, while one σ for all levels is not
    assert model.info["calibration_chi2"] == pytest.approx(1.0, abs=0.06)
    assert model_from_dict(model_to_dict(model)).pixel_noise == model.pixel_noise


def test_constant_noise_stays_one_sigma():
    recording, _ = build_rig("paper", "", seed=5).record(6.0)
    noise = estimate_pixel_noise(recording.strip(), recording.reference, recording.meta["period_mm"])
    assert not noise.signal_dependent
    assert np.sqrt(noise.read_var) == pytest.approx(0.7, rel=0.05)
    model = calibrate(recording, "paper").model
    assert model.pixel_noise is None and model.info["calibration_chi2"] == pytest.approx(1.0, abs=0.05)


def test_bound_with_a_variance_per_sample():
    rng = np.random.default_rng(0)
    slope = rng.normal(size=(4, 50))
    np.testing.assert_allclose(crlb_mm(slope, 0.7, variance=np.full(50, 0.49)), crlb_mm(slope, 0.7))
    variance = np.linspace(0.2, 2.0, 50)  # Fisher information Σ s²/σ²
    np.testing.assert_allclose(crlb_mm(slope, 1.0, variance=variance), 1 / np.sqrt((slope**2 / variance).sum(axis=1)))
