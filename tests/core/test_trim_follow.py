"""A trim never silently behind: a drift in time is followed frame by frame, and what the trim
cannot know yet is in the bound of every trimmed position (core/trim_follow.py)."""

from __future__ import annotations

import numpy as np

from graytrack.core.reference_monitor import ReferenceMonitor, Trimmer, follow
from graytrack.core.trim_follow import Follower

BOUND_MM = 1.5e-3


def _drifting(n: int, rate_um: float, seed: int, cycle: float = 0.0):
    """The stage to and fro over 10 mm; camera − grating drifting ``rate_um`` per frame (a ramp) or,
    with ``cycle`` frames, coming and going with that peak rate."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    ref = 5.0 + 4.0 * np.sin(k / 60.0)
    drift_um = rate_um * k if not cycle else rate_um * cycle / (2 * np.pi) * (1 - np.cos(2 * np.pi * k / cycle))
    x = ref + (drift_um + rng.normal(0.0, BOUND_MM * 1e3, n)) * 1e-3
    return x, ref


def _trimmed(x, ref):
    followed = follow(ReferenceMonitor(5.0, 5.0), x, ref, np.full(x.size, BOUND_MM), trim=True)
    bound_um = np.hypot(BOUND_MM * 1e3, followed.trim_sigma_um)
    return (followed.x_mm - ref) * 1e3, bound_um, followed.stale


def test_a_trim_follows_a_drift_in_time_and_is_never_silently_behind():
    """0.06 µm a frame (a 16-row strip's magnification drift: 28 µm over 500 frames), ramps and a
    cycle, three seeds: after the first trim, at most 1.3x the bound, and no frame 4+ of its
    (widened) bound off without a flag. The window's line alone lagged by half its window (9-15 µm)."""
    for seed in range(3):
        for cycle in (0.0, 300.0):
            x, ref = _drifting(1000, 0.06, seed, cycle)
            error_um, bound_um, flagged = _trimmed(x, ref)
            late = slice(100, None)
            assert np.std(error_um[late]) < 1.3 * BOUND_MM * 1e3
            far = np.abs(error_um) > 4.0 * bound_um
            assert (far & ~flagged).sum() <= 0.005 * x.size


def test_a_steady_run_is_left_alone_and_a_trim_that_cannot_keep_up_says_so():
    x, ref = _drifting(800, 0.0, seed=4)
    error_um, bound_um, flagged = _trimmed(x, ref)
    assert not flagged.any() and np.array_equal(error_um, (x - ref) * 1e3)  # no trim: nothing added
    trimmer = Trimmer(ReferenceMonitor(5.0, 5.0))
    x, ref = _drifting(400, 0.06, seed=5)
    for k in range(300):
        trimmer.feed(float(x[k]), float(ref[k]), BOUND_MM, True)
    assert trimmer.trim is not None and trimmer.following.correction_um != 0.0
    lags = []
    for k in range(300, 400):  # frames that cannot be placed: the trim ages, its lag grows into the bound
        trimmer.feed(float(x[k]), float(ref[k]), BOUND_MM, False)
        lags.append(trimmer.following.lag_um)
    assert lags[-1] > lags[0] and abs(lags[-1] - 0.06 * 100) < 3.0  # rate × age of the evidence
    assert trimmer.behind(BOUND_MM)


def test_the_follower_restates_its_evidence_when_the_trim_moves():
    follower = Follower()
    for _ in range(200):
        follower.tick()
        follower.add(2.0, 1.0)
    before = follower.now().correction_um
    follower.shift(1.5)
    assert abs(before - 2.0) < 1e-9 and abs(follower.now().correction_um - 0.5) < 1e-9



def _runs_applied(apply_z: float, runs: int = 200, frames: int = 500, spread: float = 1000.0) -> int:
    """Of ``runs`` seeded runs of noise alone (residuals of σ ``spread``, each stated with σ 1000), those on
    which a follower with threshold ``apply_z`` applied a correction on some frame."""
    rng = np.random.default_rng(7)
    applied_runs = 0
    for _ in range(runs):
        follower = Follower(memory=20.0, apply_z=apply_z)
        applied = False
        for residual in rng.normal(0.0, spread, size=frames).tolist():
            follower.tick()
            follower.add(residual, 1e6)
            applied |= follower.now().correction_um != 0.0
        applied_runs += applied
    return applied_runs


def test_noise_alone_is_not_taken_out_as_a_stretch():
    """The follower is tested on every frame: at the trim's 3σ a 500-frame run of noise alone applies
    a correction on several of 200 seeded runs (a stretch follower at 3σ took 4000 ppm out of a steady
    run), at the stretch follower's threshold (core/stretch_follow.py) on at most one."""
    from graytrack.core.stretch_follow import APPLY_Z

    assert _runs_applied(3.0) >= 5
    assert _runs_applied(APPLY_Z) <= 1


def test_a_lossy_streams_stretch_scatter_is_stated_not_left_to_the_lines_own_scatter():
    """A stream's stretches scatter 3.3x their white error (a steady `lab` run at JPEG quality 75): stated
    white, the line's own scatter estimate over a few tens of frames does not make up for it, and noise
    alone is taken out on half the runs; the stretch follower states each frame's σ widened by the
    model's stream factor (core/stretch_follow.py), which then takes nothing out."""
    from graytrack.core.stretch_follow import APPLY_Z, StretchFollow

    assert _runs_applied(APPLY_Z, frames=600, spread=3300.0) >= 50
    assert _runs_applied(APPLY_Z, frames=600, spread=1000.0) <= 1  # each σ stated 3.3x wider: the same pulls
    model = type("Model", (), {"info": {"stream": {"kind": "jpeg", "bound_factor": 3.17}}})()
    assert StretchFollow.for_model(model).noise_factor == 3.17
