"""The daemon's process-wide settings while it runs (its long-lived heap frozen out of the collector's
full passes, the cores it runs on), given back when it stops (a daemon inside a longer-lived
process, as in these tests)."""

from __future__ import annotations

import gc
import os
import subprocess
import sys

import pytest
from fastapi.testclient import TestClient

from graytrack.service.daemon.app import create_app
from tests.service.helpers import fast_settings, wait_for


def test_the_running_daemon_keeps_its_start_up_heap_frozen_and_thaws_it_at_shutdown(tmp_path) -> None:
    gc.unfreeze()
    with TestClient(create_app(fast_settings(tmp_path, auto_calibrate="never"))) as client:
        assert client.get("/healthz").status_code in (200, 503)
        # frozen once the warm-up (off the event loop, service/daemon/startup.py) has opened the rig
        wait_for(lambda: client.app.state.startup.seconds is not None and gc.get_freeze_count() > 10_000, 30.0,
                 "the warm-up and the freeze")  # the modules, the app, the drivers
    assert gc.get_freeze_count() == 0


FIRST_INSTALL = r"""
import gc, sys
import numpy as np
from graytrack.core.models.fourier import FourierModel
from graytrack.core.tracking import LiveTracker
from graytrack.service.heap import freeze_long_lived, warm_tracking

if sys.argv[1] == "warm":
    warm_tracking()
gc.collect()
freeze_long_lived()
# a model off the warm-up's path: two rows, stroke terms and a target map (the general table kernel)
model = FourierModel(period_mm=0.8, pixel_pitch_mm=0.012, n_pixels=48, harmonics=3, pixel_degree=1, n_rows=2,
                     stroke_degree=1, stroke_range_mm=(0.0, 2.0), target_map=np.full((1, 400), 1.0),
                     target_map_origin_mm=-0.5, target_map_step_mm=0.01, noise_gray=1.0)
coeffs = np.zeros(model.coeff_shape)
coeffs[0, 0], coeffs[2, 0], coeffs[5, 0, 0, 1] = 90.0, 40.0, 3.0
model = model.with_changes(coeffs=coeffs)
x = np.linspace(0.4, 0.9, 200)
frames = model.predict(x) + np.random.default_rng(1).normal(0.0, 1.0, (200, 2, 48))
tracker = LiveTracker(model, x0_mm=float(x[0]))
for frame, at in zip(frames, x):
    tracker.update(frame, float(at))
gc.collect()
print(len(gc.get_objects()))
"""


def _left_to_the_collector(warm: str) -> int:
    """Objects the collector's full passes walk after a first model install and 200 live frames."""
    done = subprocess.run([sys.executable, "-c", FIRST_INSTALL, warm], capture_output=True, text=True, check=True,
                          timeout=600)
    return int(done.stdout.split()[-1])


def test_the_warm_up_leaves_a_first_model_install_a_small_heap_for_the_collector() -> None:
    """Without the warm-up the first install brings numba's registries and kernels (tens of
    thousands of objects) into every later full pass; with it they are frozen with the start-up."""
    cold, warm = _left_to_the_collector("cold"), _left_to_the_collector("warm")
    assert cold > 20_000
    assert warm < 3_000


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="pinning needs a second core to leave")
def test_the_daemon_runs_on_its_configured_core_and_gives_the_others_back_at_shutdown(tmp_path) -> None:
    allowed = os.sched_getaffinity(0)
    core = min(allowed)
    with TestClient(create_app(fast_settings(tmp_path, auto_calibrate="never", cpu_cores=[core]))) as client:
        assert client.get("/healthz").status_code in (200, 503)
        assert os.sched_getaffinity(0) == {core}  # this thread too: every thread of the process
    assert os.sched_getaffinity(0) == allowed


def test_a_negative_core_is_refused_with_the_setting_named(tmp_path) -> None:
    with pytest.raises(ValueError, match="cpu_cores"):
        fast_settings(tmp_path, cpu_cores=[-1])
