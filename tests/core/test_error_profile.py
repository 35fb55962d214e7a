"""The calibration's error profile along the stroke (core/adequacy.py ``error_profile``) counts the
error fixed there, which the frames next to each other share, not an error that did not repeat: a
run passes the place at other instants (core/watches/adequacy.py flags every frame placed in a
stretch beyond its limit, on every run)."""

from __future__ import annotations

import numpy as np

from graytrack.core.adequacy import PROFILE_FRAMES, error_profile
from graytrack.core.watches.adequacy import LOCAL_LIMIT

BOUND_MM = 3e-4
N = 40 * PROFILE_FRAMES


def _sweep(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One sweep over 10 mm, every frame's error at its bound (seeded)."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, 10.0, N)
    return x, BOUND_MM * rng.standard_normal(N), np.full(N, BOUND_MM**2)


def _stretch_of(edges: list[float], x: float) -> int:
    return int(np.searchsorted(edges, x, side="right") - 1)


def test_a_lone_frame_off_does_not_flag_its_stretch_a_fixed_error_does():
    """One frame 15 bounds off (a light taken for a shadow's band on one frame of the steady telegraph
    strip) lifted its stretch's rms to 3.2x: every run's frames there were flagged ``geometry``. A
    scratch's error, 3 bounds on every frame of a stretch (it moves with the print, so the frames
    around it see it too), still flags it."""
    for seed in range(5):
        x, error, bound2 = _sweep(seed)
        error[252] += 15 * BOUND_MM  # in stretch 10
        error[750:775] += 3 * BOUND_MM * (1 + 0.1 * np.sin(np.arange(25) / 4))  # stretch 30, smooth along x
        profile = error_profile(x, error, bound2)
        edges, ratio = profile["edges_mm"], np.array(profile["ratio"])
        assert ratio[_stretch_of(edges, x[252])] < 1.8  # the old rms: 3.2x, beyond the limit
        assert ratio[_stretch_of(edges, x[760])] > 1.15 * LOCAL_LIMIT  # (√10 less its ends: 2.9-3.2x)
        assert (ratio > LOCAL_LIMIT).sum() == 1


def test_an_error_on_one_pass_only_is_no_error_of_the_place():
    """Two passes over the stroke, interleaved in place; a transient 4 bounds off for 12 frames of the
    first pass (a telegraph pixel up for a quarter second) is not on the second at the same place:
    not flagged (the old rms: 2.6x). The same error on both passes (the print's) is."""
    rng = np.random.default_rng(7)
    x = np.concatenate((np.linspace(0.0, 10.0, N // 2), np.linspace(10.0, 0.0, N // 2) + 0.002))
    error = BOUND_MM * rng.standard_normal(N)
    bound2 = np.full(N, BOUND_MM**2)
    first = np.arange(250, 262)
    once = error.copy()
    once[first] += 4 * BOUND_MM
    profile = error_profile(x, once, bound2)
    assert max(profile["ratio"]) < LOCAL_LIMIT
    twice = once.copy()
    twice[N - 1 - first] += 4 * BOUND_MM  # the second pass, at the same places
    profile = error_profile(x, twice, bound2)
    edges, ratio = profile["edges_mm"], np.array(profile["ratio"])
    assert ratio[_stretch_of(edges, x[256])] > LOCAL_LIMIT
