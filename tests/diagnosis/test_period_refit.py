"""τ_w refined again once the layers a seed model lacked are known.

Stray light from a reflection in the lens (a bright blob fixed to the camera, nothing any issue
names) pulls the seed paper's fit of the period; a model that then holds that period fits every
image to its noise and still places the frames at twice their bound, the stroke's ends far off the
grating. Refined in the second alternation round, with the flat field known, τ_w comes back."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core import effects
from graytrack.core.calibration import KIND_SPECS
from graytrack.core.calibration_data import calibration_data
from graytrack.core.diagnosis import diagnose
from graytrack.core.geometry import initial_geometry
from graytrack.core.structure import fit_spec
from graytrack.core.tracking import track
from graytrack.drivers.sim.scenarios import build_rig

GLARE = "glare"  # the rig effect's defaults: 20 gray at its centre, 8 px across, on a 16-row strip


@pytest.fixture(scope="module")
def glare_calibration():
    """The strip's calibration run under the glare, recorded once for both tests (the tests only read it)."""
    return build_rig("strip16", GLARE, seed=3).record(8.0)[0]


def test_stray_light_pulls_the_seed_period_and_the_flat_field_fit_brings_it_back(glare_calibration) -> None:
    recording = glare_calibration
    data = calibration_data(recording)
    true_mm = recording.meta["period_mm"]
    seed = fit_spec(KIND_SPECS["paper"], data, *initial_geometry(data)).model
    assert abs(seed.period_mm / true_mm - 1) > 150e-6  # the premise: the seed's τ_w is pulled
    spec = effects.registry()["flat_field"].grow(KIND_SPECS["paper"], None)
    flat = fit_spec(spec, effects.prepare_data(spec, data), seed.period_mm, seed.pixel_pitch_mm,
                    refine_geometry=False).model
    assert abs(flat.period_mm / true_mm - 1) < 50e-6
    stroke = spec.with_changes(stroke_degree=1)  # stroke terms turn the phase as τ_w does: it is held
    held = fit_spec(stroke, effects.prepare_data(stroke, data), seed.period_mm, seed.pixel_pitch_mm,
                    refine_geometry=False).model
    assert held.period_mm == seed.period_mm


def test_the_closed_loop_on_stray_light_tracks_another_run_at_its_bound(glare_calibration) -> None:
    calibration = glare_calibration
    run, _ = build_rig("strip16", GLARE, seed=3, run=1).record(4.0)
    loop = diagnose(calibration)
    assert "flat_field" in [step.effect for step in loop.steps]
    tracked = track(loop.final_model, run, light="auto", robust=True)
    error = tracked.error_um(run.reference)
    bound = float(np.sqrt(np.nanmean(np.square(tracked.crlb_mm * 1e3))))
    assert np.isfinite(error).all()
    assert np.std(error) < 1.25 * bound  # 2x with the seed's τ_w held
    assert not tracked.stale.any()
