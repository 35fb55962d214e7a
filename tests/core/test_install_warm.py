"""A live tracker compiles and builds everything at model install: no live frame waits for the
compiler, a table or the validity monitor (a first blurred frame once stalled the daemon ~40 ms loading the general
focus solve from numba's cache, seconds on a fresh install with no cache).

Each case runs in a fresh interpreter, where numba's dispatchers start with no compiled signature:
in this process other tests have compiled them already, and the check could not fail."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent("""
    import json, sys
    from numba.core.registry import CPUDispatcher
    from graytrack.core.calibration import calibrate
    from graytrack.core.tracking import LiveTracker
    from graytrack.service.grown_models import model_with
    from graytrack.drivers.sim.scenarios import build_rig

    kind = sys.argv[1]
    trouble = "defocus:sigma_um=200,focus_drift:px=1:start_s=0.1,glints:p=0.3,bad_pixels,light_change:start_s=0.2"
    if kind == "plain":
        calibration, _ = build_rig("paper", "defocus:sigma_um=200", seed=4).record(2.0)
        model = calibrate(calibration, "paper").model
    else:
        model = model_with("stroke", seconds=1.0)[0]
    run, _ = build_rig("paper", trouble, seed=4, run=1).record(0.5)

    def compiled():
        return {f"{module.__name__}.{name}": len(value.signatures)
                for module in list(sys.modules.values()) if getattr(module, "__name__", "").startswith("graytrack")
                for name, value in list(vars(module).items()) if isinstance(value, CPUDispatcher)}

    from graytrack.core import tracking

    solves = [0]  # frames that reach the focus solve (whether their answer keeps the term or not)
    for name in ("focus_solve", "general_focus_solve"):
        def counted(*args, _solve=getattr(tracking, name), **kwargs):
            solves[0] += 1
            return _solve(*args, **kwargs)
        setattr(tracking, name, counted)

    tracker = LiveTracker(model, x0_mm=float(run.reference[0]))
    installed = compiled()
    monitor_ready = tracker.state.monitor is not None
    placed = 0
    for frame, grating in zip(run.frames, run.reference):
        fix = tracker.update(frame, grating)
        placed += fix.x_mm == fix.x_mm
    focused = solves[0]
    after = compiled()
    print(json.dumps({"fast_path": bool(tracker.tracker.fast_path), "frames": len(run.frames), "placed": int(placed),
                      "focused": int(focused), "monitor_ready": monitor_ready,
                      "late": {k: v for k, v in after.items() if v != installed.get(k, 0)}}))
""")


@pytest.mark.parametrize("kind, fast_path", [("plain", True), ("stroke", False)])
def test_a_live_tracker_compiles_nothing_on_a_live_frame(kind: str, fast_path: bool) -> None:
    done = subprocess.run([sys.executable, "-c", SCRIPT, kind], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["fast_path"] is fast_path
    assert report["focused"] > 0, "the frames must reach the focus solve, or the check proves nothing"
    assert report["placed"] > report["frames"] // 2
    assert report["late"] == {}, f"compiled on a live frame: {report['late']}"
    assert report["monitor_ready"], "the validity monitor's tables are model install's work, not the first frame's"


ESTIMATOR_SCRIPT = textwrap.dedent("""
    import json, sys
    import numpy as np
    from numba.core.registry import CPUDispatcher
    from graytrack.core.calibration import calibrate
    from graytrack.core.estimator.live import LiveEstimator
    from graytrack.drivers.sim.scenarios import build_rig

    calibration, _ = build_rig("paper", "", seed=4).record(2.0)
    model = calibrate(calibration, "paper").model
    run, _ = build_rig("paper", "light_change:start_s=0.2", seed=4, run=1).record(0.5)

    def compiled():
        return {f"{module.__name__}.{name}": len(value.signatures)
                for module in list(sys.modules.values()) if getattr(module, "__name__", "").startswith("graytrack")
                for name, value in list(vars(module).items()) if isinstance(value, CPUDispatcher)}

    trackers = {mode: LiveEstimator(model, x0_mm=float(run.reference[0]), grating=mode)
                for mode in ("check", "fuse", "none")}
    installed = compiled()
    # every kind of frame a camera or a recording hands over: 8- and 16-bit codes, float32, float64
    kinds = (lambda f: f, lambda f: np.clip(f, 0, 255).astype(np.uint8),
             lambda f: np.clip(f * 16, 0, 4095).astype(np.uint16), lambda f: f.astype(np.float64))
    placed, jumps = 0, 0
    for mode, tracker in trackers.items():
        for k, (frame, grating) in enumerate(zip(run.frames, run.reference)):
            fix = tracker.update(kinds[k % len(kinds)](frame), float(grating), float(run.t[k]))
            placed += fix.x_mm == fix.x_mm
            jumps += bool(tracker.last.mode)
    after = compiled()
    print(json.dumps({"frames": 3 * len(run.frames), "placed": int(placed), "jumps": jumps,
                      "late": {k: v for k, v in after.items() if v != installed.get(k, 0)}}))
""")


def test_a_live_estimator_compiles_nothing_on_a_live_frame() -> None:
    done = subprocess.run([sys.executable, "-c", ESTIMATOR_SCRIPT], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["placed"] > report["frames"] // 2
    assert report["jumps"] > 0, "the frames must take a jump (the update solved again), or the check proves less"
    assert report["late"] == {}, f"compiled on a live frame: {report['late']}"


WARM_SCRIPT = textwrap.dedent("""
    import dataclasses, json, sys
    import numpy as np
    from numba.core.registry import CPUDispatcher
    from graytrack.core.calibration import calibrate
    from graytrack.core.estimator.live import LiveEstimator
    from graytrack.core.tracking import LiveTracker
    from graytrack.drivers.sim.scenarios import build_rig
    from graytrack.service.heap import warm_tracking

    calibration, _ = build_rig("paper", "", seed=4).record(2.0)
    model = calibrate(calibration, "paper").model
    weight = np.ones((1, model.n_pixels))
    weight[0, [7, 40]] = 0.0
    masked = dataclasses.replace(model, pixel_weight=weight)  # two pixels found bad: their offset and gain read 0

    def compiled():
        return {f"{module.__name__}.{name}": len(value.signatures)
                for module in list(sys.modules.values()) if getattr(module, "__name__", "").startswith("graytrack")
                for name, value in list(vars(module).items()) if isinstance(value, CPUDispatcher)}

    warm_tracking(("watches", "estimator"))
    warmed = compiled()
    for each in (model, masked):
        LiveTracker(each, x0_mm=1.0)
        LiveEstimator(each, x0_mm=1.0, grating="fuse")
    after = compiled()
    print(json.dumps({"late": {k: v for k, v in after.items() if v != warmed.get(k, 0)}}))
""")


def test_the_warm_up_compiles_what_every_model_needs() -> None:
    """The warm-up (a synthetic model, before the test workers and at the daemon's start) compiles the kernels
    that every calibrated model then loads: a model whose bad pixels are masked (a read-only array once went
    into the kernels' arguments, another type: every kernel compiled again, ~20 s of CPU a process) included."""
    done = subprocess.run([sys.executable, "-c", WARM_SCRIPT], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["late"] == {}, f"compiled after the warm-up: {report['late']}"
