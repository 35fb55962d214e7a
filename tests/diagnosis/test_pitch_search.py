"""The α·d search a target map needs, started where an earlier search of the same loop found it:
the same valley, for a fraction of the fits (a 16-row lab strip spent 11 minutes of one closed-loop
step on a full scan with every structure it had grown)."""

from __future__ import annotations

import pytest

from graytrack.core import effects, structure
from graytrack.core.calibration import KIND_SPECS
from graytrack.core.calibration_data import calibration_data
from graytrack.core.geometry import initial_geometry
from graytrack.drivers.sim.scenarios import build_rig


@pytest.fixture(scope="module")
def dusty():
    """(map spec, its data, period, starting α·d, the α·d a full search finds) on a dusty print."""
    recording, _ = build_rig("paper", "dust:count=6", seed=3).record(8.0)
    spec = effects.registry()["target_map"].grow(KIND_SPECS["paper"], None)
    data = effects.prepare_data(spec, calibration_data(recording))
    period_mm, pitch_mm, _ = initial_geometry(data)
    found = structure.fit_spec_pitch_search(spec, data, period_mm, pitch_mm).model.pixel_pitch_mm
    return spec, data, period_mm, pitch_mm, found


def test_a_search_started_at_the_found_pitch_finds_it_again_with_about_a_third_of_the_fits(dusty, monkeypatch) -> None:
    spec, data, period_mm, pitch_mm, found = dusty
    fits = []
    fit = structure.fit_spec

    def counted(*args, **kwargs):
        fits.append(kwargs.get("searching", False))
        return fit(*args, **kwargs)

    monkeypatch.setattr(structure, "fit_spec", counted)
    structure.fit_spec_pitch_search(spec, data, period_mm, pitch_mm)
    full = len(fits)
    fits.clear()
    again = structure.fit_spec_pitch_search(spec, data, period_mm, pitch_mm, found_mm=found).model.pixel_pitch_mm
    assert again == pytest.approx(found, rel=1e-3)  # the search's tolerance is 2e-4 of α·d
    assert len(fits) <= 0.4 * full  # 12 of 34 on this print
    assert fits.count(False) == 1  # only the last fit is the model's; every other is a point of the search


def test_a_found_pitch_the_scan_does_not_bracket_falls_back_to_the_whole_span(dusty) -> None:
    spec, data, period_mm, pitch_mm, found = dusty
    wrong = structure.fit_spec_pitch_search(spec, data, period_mm, pitch_mm, found_mm=found * 1.08)
    assert wrong.model.pixel_pitch_mm == pytest.approx(found, rel=1e-3)
