"""The live camera's one-frame renderer (drivers/sim/frame_render.py) gives the rig's own frames.

For every registered effect: where the renderer folds the light into its precomputed matrix, the
noise-free light agrees with :meth:`VirtualRig.render_light` to 1e-9 gray (still and moving
exposures, flicker phases), and a rendered frame — noise drawn from the same stream — agrees with
:meth:`VirtualRig.render` to float32 rounding (1e-3 gray; at most one count where the sensor
quantises). Where it cannot, it says why and the frame is the direct render's, draw for draw.
"""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.drivers.sim.frame_render import FrameRenderer
from graytrack.drivers.sim.scenarios import build_rig, list_effects

LIGHT_TOL_GRAY = 1e-9
FRAME_TOL_GRAY = 1e-3  # float32 arithmetic of the sensor on light that differs in its last bits
# exposures: (positions over the exposure, mid-instant): still, a slow sweep, a fast move with flicker
EXPOSURES = [(np.array([3.1]), 0.0), (np.array([1.0, 1.0004, 1.0008]), 0.25),
             (np.array([7.0, 7.05, 7.1, 7.15, 7.2]), 1.3731)]
# the effects the renderer cannot fold: their light depends on each pixel's own target coordinate or time
DIRECT = {"chirp", "dust", "dust_settling", "scratches", "smudge", "target_growth", "gradient", "focus_drift",
          "focus_cycle", "glints", "rolling_shutter", "magnification_drift", "knock"}


def _rigs(effect: str, scenario: str = "strip16"):
    """Two identical rigs (same seed, same noise stream): one rendered directly, one by the renderer."""
    return build_rig(scenario, [effect], seed=3), build_rig(scenario, [effect], seed=3)


@pytest.mark.parametrize("effect", sorted(list_effects()))
def test_renderer_matches_direct_render(effect: str) -> None:
    direct, fast = _rigs(effect)
    renderer = FrameRenderer(fast)
    exposure = direct.exposure_s
    for x, t in EXPOSURES:
        if renderer.fallback is None:
            want = direct.render_light(x[None], np.array([t]))
            got = renderer.light(x, t, exposure)
            assert got.shape == want.shape
            assert np.max(np.abs(got - want)) <= LIGHT_TOL_GRAY
        frame_direct = direct.render(x[None], np.array([t]))[0]
        frame_fast = renderer.render(x, t, exposure)
        assert frame_fast.dtype == frame_direct.dtype and frame_fast.shape == frame_direct.shape
        diff = np.abs(frame_fast.astype(np.float64) - frame_direct.astype(np.float64))
        if renderer.fallback is not None:
            assert np.array_equal(frame_fast, frame_direct)
        elif np.issubdtype(frame_direct.dtype, np.integer):
            assert diff.max() <= 1 and np.mean(diff > 0) <= 0.01  # a rounding at a count's edge, rarely
        else:
            assert diff.max() <= FRAME_TOL_GRAY


def test_what_falls_back_is_named() -> None:
    """Only the effects that cannot be folded fall back, and each says why (a slow camera is never silent)."""
    falling = set()
    for effect in list_effects():
        reason = FrameRenderer(build_rig("strip16", [effect])).fallback
        if reason is not None:
            assert len(reason) > 5
            falling.add(effect)
    assert falling <= DIRECT
    assert FrameRenderer(build_rig("lab")).fallback is not None  # a chirped, defective lab print


@pytest.mark.parametrize("scenario", ["paper", "clean", "strip16", "highspeed"])
def test_daemon_scenarios_take_the_fast_path(scenario: str) -> None:
    """The scenarios a daemon streams at 1 kHz are folded, and their frames are the rig's."""
    direct, fast = build_rig(scenario, seed=1), build_rig(scenario, seed=1)
    renderer = FrameRenderer(fast)
    assert renderer.fallback is None
    x = np.array([2.0, 2.001, 2.002])
    frames = [renderer.render(x + 0.01 * k, 0.001 * k, direct.exposure_s) for k in range(50)]
    want = np.stack([direct.render((x + 0.01 * k)[None], np.array([0.001 * k]))[0] for k in range(50)])
    assert np.max(np.abs(np.stack(frames).astype(np.float64) - want)) <= FRAME_TOL_GRAY
    # the noise is the rig's: the same spread over the frames (read noise 0.7 gray in these scenarios)
    residual = np.stack(frames).astype(np.float64) - direct.render_light(np.stack([x + 0.01 * k for k in range(50)]),
                                                                          0.001 * np.arange(50))
    assert 0.6 < residual.std() < 0.8
