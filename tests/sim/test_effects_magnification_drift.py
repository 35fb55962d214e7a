"""The ``magnification_drift`` effect: the footprint scaling in time about an optical axis off the ROI."""

from __future__ import annotations

import numpy as np

from graytrack.drivers.sim import paper

from .helpers import light, quiet_rig


def test_magnification_drift_renders_as_a_static_magnification_slid_by_its_change_times_the_axis():
    """At time t the image is the static ``magnification`` rig of m(t), slid by m(t) × (ROI centre −
    axis): a ramp reaches its ppm at ramp_s (half of it halfway), a cycle comes and goes."""
    pitch, axis_px = paper.PIXEL_PITCH_MM, 300.0
    centre = pitch * (paper.N_PIXELS - 1) / 2  # the ROI's centre on the target (ROI origin at 0)
    x = np.linspace(0.0, 5.0, 4)

    def expected(m: float) -> np.ndarray:
        static = quiet_rig("paper", [f"magnification:percent={m * 100}"])
        return light(static, x - m * (centre + axis_px * pitch), np.zeros_like(x))

    ramp = quiet_rig("paper", [f"magnification_drift:ppm=2000:axis_px={axis_px}:start_s=1:ramp_s=4"])
    np.testing.assert_allclose(light(ramp, x, np.zeros_like(x)), light(quiet_rig("paper"), x), atol=1e-9)
    np.testing.assert_allclose(light(ramp, x, np.full(4, 3.0)), expected(1e-3), atol=1e-6)
    np.testing.assert_allclose(light(ramp, x, np.full(4, 9.0)), expected(2e-3), atol=1e-6)
    cycle = quiet_rig("paper", [f"magnification_drift:ppm=2000:axis_px={axis_px}:cycle_s=6"])
    np.testing.assert_allclose(light(cycle, x, np.full(4, 3.0)), expected(2e-3), atol=1e-6)
    np.testing.assert_allclose(light(cycle, x, np.full(4, 6.0)), light(quiet_rig("paper"), x), atol=1e-6)
