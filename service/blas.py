"""One BLAS thread in the processes that track frame by frame.

The per-frame linear algebra is small (a residual's projection onto a few shapes, ≤ 2,048 × 20):
a second BLAS thread gains nothing on it, and OpenBLAS's workers spin between calls. In the
daemon they took the cores from its own frame loop, the virtual rig and the stream's clients: at
1,000 frames/s on a 2-core machine a 16-row closed-loop model dropped a third of the camera
frames, at 133 % CPU. Calibration's large fits lose a little speed in exchange.
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)
_BEFORE: list[int] = []  # what the first call found: the limit then holds for the rest of the process


def single_threaded_blas() -> int | None:
    """Limit numpy's and scipy's BLAS libraries (loaded here, so that the limit reaches both) to one
    thread for the rest of the process; returns the most threads any had before (None:
    threadpoolctl is missing). Once limited, a process is not searched again (a command run twice
    in one process, as the benches and the tests run it, paid the search each time)."""
    if _BEFORE:
        return _BEFORE[0]
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - a dependency; without it only speed is lost
        log.warning("threadpoolctl missing: BLAS keeps its own thread count")
        return None
    import numpy  # noqa: F401 - load the BLAS libraries the limit applies to (each wheel brings its own)
    import scipy.linalg  # noqa: F401

    # one controller for both: finding the loaded libraries is the call's whole cost (~1.5 ms each time,
    # paid by every `graytrack track`), and threadpool_info / threadpool_limits each found them anew
    controller = ThreadpoolController()
    before = max((pool.get("num_threads", 1) for pool in controller.info() if pool.get("user_api") == "blas"),
                 default=1)
    controller.limit(limits=1, user_api="blas")
    _BEFORE.append(before)
    return before
