"""Focus drifting while the calibration sweep records (a lens still warming up): the focus effect
fits one change of blur per frame along ∂S/∂δ (each harmonic m times −2π²(m/τ)²), so the model
is the target at one focus, not a blend that tracks a steady run off its bound. Its probe finds
the drift in the held-out residual and stays silent when the focus holds."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate, calibration_data
from graytrack.core.diagnosis import diagnose
from graytrack.core.diagnosis.loop import all_evidence
from graytrack.core.structure import ModelSpec, fit_spec
from graytrack.core.tracking import track
from graytrack.drivers.sim.optics import blur_sigma_mm
from graytrack.drivers.sim.scenarios import build_rig

BASE = "defocus:sigma_um=200"
DRIFTING = f"{BASE},focus_drift:px=1:start_s=0:ramp_s=16"  # σ grows by a pixel over the 16 s sweep


def ratio(model, run) -> float:
    result = track(model, run, light="auto", robust=True)
    error = result.error_um(run.reference)
    return float(np.nanstd(error) / np.sqrt(np.nanmean(np.square(result.crlb_mm * 1e3))))


def test_a_focus_drifting_during_calibration_is_fitted_per_frame_and_the_model_tracks_at_the_bound():
    rig = build_rig("strip16", DRIFTING, seed=3)
    recording, _ = rig.record(16.0)
    plain = calibrate(recording, "paper").model
    spec = ModelSpec().set("focus", True)
    focused = fit_spec(spec, calibration_data(recording), plain.period_mm, plain.pixel_pitch_mm).model
    optics = rig.config.optics
    variance = blur_sigma_mm(optics, recording.t) ** 2 / optics.pixel_pitch_mm**2
    assert focused.info["calibration_focus_spread_px2"] == pytest.approx(float(np.std(variance)), rel=0.15)
    low, high = focused.info["calibration_focus_range_px2"]
    assert low < -0.8 * np.ptp(variance) / 2 and high > 0.8 * np.ptp(variance) / 2  # noisy per frame: wider
    run, _ = build_rig("strip16", BASE, seed=3, run=1).record(8.0)  # measured at the sweep's starting focus
    assert ratio(focused, run) <= 1.2
    assert ratio(plain, run) > 1.25  # the blend: what the effect is for


@pytest.mark.parametrize("effects_", [BASE, DRIFTING])
def test_the_probe_sees_a_drifting_focus_and_not_a_steady_one(effects_):
    recording, _ = build_rig("strip16", effects_, seed=3).record(16.0)
    loop = diagnose(recording)
    evidence = {ev.effect: ev for ev in all_evidence(loop.before)}
    if effects_ == BASE:
        assert evidence["focus"].z < 5.0
    else:
        assert evidence["focus"].z > 50.0 and evidence["focus"] is max(evidence.values(),
                                                                       key=lambda ev: ev.explained_gray2)
        run, _ = build_rig("strip16", BASE, seed=3, run=1).record(8.0)
        assert ratio(loop.final_model, run) <= 1.2


def test_focus_and_a_target_map_fit_together():
    """Both bilinear effects keep findings in the alternation's shared record: the map's step must
    take only its own (a focus found before it once broke the loop on the lab rig's MJPEG case)."""
    recording, _ = build_rig("paper", "dust:count=4," + DRIFTING, seed=3).record(12.0)
    plain = calibrate(recording, "paper").model
    spec = ModelSpec().set("focus", True).set("target_map", 64)
    model = fit_spec(spec, calibration_data(recording), plain.period_mm, plain.pixel_pitch_mm).model
    assert model.target_map is not None and "calibration_focus_spread_px2" in model.info
