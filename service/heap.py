"""The daemon's long-lived objects kept out of the cyclic garbage collector's full passes.

A full (oldest-generation) collection walks every container object the process holds: with
FastAPI, numba, scipy and a calibrated model loaded that is ~120,000 objects and 20–70 ms with
the GIL held, on whichever thread happens to allocate. At 1,000 frames/s that is a burst of 20 to
70 late frames every few seconds, the stream's p99. The objects alive once the daemon has started
(modules, the app, the drivers) live as long as the process: moved into the permanent
generation, full passes walk only what came after. Reference counting still frees them; only a
cycle among them would outlive its use, and they are built once. (A model install's tables are
left to the collector: frozen from the builder thread, they changed when a wrong model's stale
flag was seen to flicker in tests/service/test_metrics.py, a timing the freeze should not touch;
not understood yet, so not done.)
"""

from __future__ import annotations

import gc


def freeze_long_lived() -> int:
    """Every object tracked now into the permanent generation; returns how many it holds.
    Cheap (a list splice, no walk): it may run on any thread."""
    gc.freeze()
    return gc.get_freeze_count()


def thaw() -> None:
    """Back into the oldest generation (a daemon shut down inside a longer-lived process: tests)."""
    gc.unfreeze()
