"""The daemon's long-lived objects kept out of the cyclic garbage collector's full passes.

A full (oldest-generation) collection walks every container object the process holds: with
FastAPI, numba, scipy and a calibrated model loaded that is ~120,000 objects and 20–70 ms with
the GIL held, on whichever thread happens to allocate. At 1,000 frames/s that is a burst of 20 to
70 late frames every few seconds, the stream's p99. The objects alive once the daemon has started
(modules, the app, the drivers) live as long as the process: moved into the permanent
generation, full passes walk only what came after. Reference counting still frees them; only a
cycle among them would outlive its use, and they are built once.

Left to the first model install, most of the heap would come with it: numba builds its typing
registries and loads the compiled kernels on first use, ~50,000 objects that live as long as the
process, and a full pass over them takes 15–25 ms (over 100 ms seen with the cores busy) on the
event loop's thread in the middle of the stream. :func:`warm_tracking` runs a small synthetic
model through a live tracker before the freeze, so they are frozen with the rest; a model
installed later then leaves ~600 objects to the collector (full pass ~0.2 ms). A model's own
tables are not frozen: a replaced model caught in a cycle would never be freed.
"""

from __future__ import annotations

import gc

import numpy as np

WARM_FRAMES = 40  # frames of the synthetic run: acquisition, the sequential solve and every watch's first steps


def freeze_long_lived() -> int:
    """Every object tracked now into the permanent generation; returns how many it holds.
    Cheap (a list splice, no walk): it may run on any thread."""
    gc.freeze()
    return gc.get_freeze_count()


def thaw() -> None:
    """Back into the oldest generation (a daemon shut down inside a longer-lived process: tests)."""
    gc.unfreeze()


def warm_tracking(engines: tuple[str, ...] = ("watches",)) -> None:
    """Track a synthetic sine target with a synthetic model, frame by frame as the daemon does, with each
    per-frame path of ``engines`` (``[daemon] engine``'s values): what tracking loads on first use is loaded
    now (from numba's disk cache: ~0.5 s; compiled on a fresh install: tens of seconds, which the first
    model install would otherwise pay)."""
    from graytrack.core.estimator.live import LiveEstimator
    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.tracking import LiveTracker

    model = FourierModel(period_mm=0.5, pixel_pitch_mm=0.01, n_pixels=64, harmonics=1, pixel_degree=0,
                         noise_gray=1.0, name="warm-up")
    coeffs = np.zeros(model.coeff_shape)
    coeffs[0], coeffs[2] = 100.0, 50.0  # offset and the fundamental's cosine
    model = model.with_changes(coeffs=coeffs)
    noise = np.random.default_rng(0).normal(0.0, 1.0, (WARM_FRAMES, model.n_pixels))
    x_mm = np.linspace(0.1, 0.3, WARM_FRAMES)
    frames = model.predict(x_mm)[:, 0] + noise
    if "watches" in engines:
        tracker = LiveTracker(model, x0_mm=float(x_mm[0]))
        for frame, x in zip(frames, x_mm):
            tracker.update(frame, float(x))
    if "estimator" in engines:
        estimator = LiveEstimator(model, x0_mm=float(x_mm[0]))
        for k, (frame, x) in enumerate(zip(frames, x_mm)):
            estimator.update(frame, float(x), k * 1e-3)
