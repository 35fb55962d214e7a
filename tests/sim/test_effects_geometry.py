"""Physical signatures of the set-up faults: a mirrored camera, a lens imaging at another scale
than the nominal α·d says, an ROI partly off the print."""

from __future__ import annotations

import numpy as np
import pytest

from .helpers import light, quiet_rig


def test_mirrored_reverses_which_target_point_each_column_sees():
    plain, mirrored = quiet_rig(), quiet_rig(effects=["mirrored"])
    x_plain, x_mirrored = plain.geometry.x_mm[0], mirrored.geometry.x_mm[0]
    np.testing.assert_allclose(x_mirrored, x_plain[::-1], atol=1e-12)  # the same span, read the other way
    assert np.all(np.diff(x_mirrored) < 0)
    positions = [0.7, 4.2]
    np.testing.assert_allclose(light(mirrored, positions), light(plain, positions)[..., ::-1], atol=1e-9)
    assert mirrored.meta()["pixel_pitch_mm"] == plain.meta()["pixel_pitch_mm"]  # nothing in the file says so


def test_magnification_scales_the_footprint_but_not_the_nominal_figure():
    rig = quiet_rig(effects=["magnification:percent=20"])
    step = np.diff(rig.geometry.x_mm[0])
    np.testing.assert_allclose(step, 0.062 * 1.2, rtol=1e-12)
    assert rig.meta()["pixel_pitch_mm"] == pytest.approx(0.062)


def test_off_target_columns_see_a_plain_surface_wherever_the_stage_is():
    rig = quiet_rig(effects=["off_target:share=0.3:gray=200"])
    values = light(rig, [0.5, 2.0, 6.1])[:, 0]
    np.testing.assert_allclose(values[:, 70:], 200.0, atol=1e-9)
    assert values[:, :70].std(axis=0).min() > 10.0  # the rest still sees the print move by


def test_off_target_rows_of_a_strip_see_no_print():
    rig = quiet_rig("strip16", effects=["off_target:share=0:rows=4:gray=150"])
    values = light(rig, [0.5, 2.0, 6.1])
    np.testing.assert_allclose(values[:, :4], 150.0, atol=1e-9)
    assert values[:, 4:].std(axis=0).min() > 1.0
