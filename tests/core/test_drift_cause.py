"""What drifted the line camera − grating (core/drift_cause.py): a lens, a grown print or neither,
from the image's stretch and the line's scale since calibration together."""

from __future__ import annotations

import pytest

from graytrack.core.drift_cause import explanations, lens_favoured


def test_a_scale_no_print_matches_and_no_grating_makes_is_a_lens_before_its_stretch_is_significant():
    """The paper rig's 0.15 % lens ramp at its frame 59 (seed 3): the line's scale −2034 ± 495 ppm, the
    stretch 209 ± 281, within 1σ of none. A print that read that scale would have stretched its image by
    as much, and no grating warms by 2000 ppm: the lens (the stretch alone named it at frame 234)."""
    told = explanations(209.0, 281.0, -2034.0, 495.0 ** 2)
    assert told["lens"] > told["none"] + 1.0 and told["lens"] > told["print"] + 1.0
    assert lens_favoured(209.0, 281.0, -2034.0, 495.0 ** 2)


@pytest.mark.parametrize("mean_ppm, sigma_ppm, scale_ppm, scale_sigma_ppm, why", [
    (-250.0, 200.0, -250.0, 40.0, "a print grown 250 ppm: its stretch is its scale"),
    (-2100.0, 200.0, -2034.0, 150.0, "a print grown 2000 ppm, stretched as much"),
    (120.0, 280.0, 30.0, 60.0, "the line shifted (a camera moved on its mount): no scale, no stretch"),
    (120.0, 280.0, 60.0, 1000.0, "a stage at rest: its scale unseen, the stretch within 1σ"),
])
def test_a_print_or_a_shift_is_not_taken_for_a_lens(mean_ppm, sigma_ppm, scale_ppm, scale_sigma_ppm, why):
    assert not lens_favoured(mean_ppm, sigma_ppm, scale_ppm, scale_sigma_ppm ** 2), why


def test_the_stretch_alone_tells_without_a_line():
    """No line (its scale not finite): no print can be told, a stretch beyond ~2.2σ is a lens's."""
    assert lens_favoured(700.0, 200.0, float("nan"), 0.0)
    assert not lens_favoured(300.0, 200.0, float("nan"), 0.0)
    assert explanations(300.0, 200.0, float("nan"), 0.0)["print"] == float("-inf")
