"""Pipelined requests against a real ``graytrack serve`` (issue #48, service/daemon/limits.py): ten
connections writing ``GET /api/status`` 100 at a time without waiting, reading what comes back, against
quiet windows of the same length just before and after, on the same daemon. Before the protocol parsed one request
at a time, this grew the daemon by hundreds of MB (kept after close) and the frame loop lost a large part
of its frames; while the budget counted requests but not what they cost (3.7 ms of CPU each, not the 1 ms
assumed), the flood's 180 answers a second still lost 5 % of the frames (``[daemon] serving_share`` now bounds
what serving is measured to take). bench/pipeline_flood.py prints the same figures over 20 s.

Marked ``alone``: the frame loop's losses follow the host's load, so the flood and its quiet window need
the machine to themselves (make test runs these after the rest, serially).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.service.helpers import ServeProcess
from tests.service.hostile import FLOOD_RIG, quiet_flood_quiet

pytestmark = pytest.mark.alone

FLOOD_S = 8.0  # the claim holds from the first seconds (the old code had grown by 500+ MB by then)
CONNECTIONS = 10
RSS_GROWTH_MB = 40.0  # issue #48's acceptance
# The host's load alone moves a window's losses: quiet windows of 8-10 s on this 2-core machine shared with
# other jobs lost 0 to 61 of ~1,600-2,000 frames. So the flood's may exceed the worse of the quiet windows
# around it by 2 % of its frames and 5 (the old code lost half of them).
NOISE_FRACTION = 0.02
NOISE_FRAMES = 5


def test_a_pipelined_flood_leaves_memory_flat_and_the_rig_untouched(tmp_path: Path) -> None:
    with ServeProcess(tmp_path, **FLOOD_RIG) as daemon:
        daemon.wait_state("tracking", timeout_s=120)
        figures = quiet_flood_quiet(daemon.base, daemon.process.pid, daemon.port, FLOOD_S, CONNECTIONS)
        alive = daemon.status()
        assert daemon.terminate() == 0
    flood, during = figures.client, figures.flood
    quiet = [figures.quiet, figures.quiet_after]
    shown = (f"RSS {figures.rss_before_mb:.0f} -> peak {figures.rss_peak_mb:.0f} -> {figures.rss_after_mb:.0f} MB; "
             f"quiet {quiet[0]}; flood {during}; quiet after {quiet[1]}; {flood.answers} answers {flood.statuses}, "
             f"errors {flood.errors[:3]}")
    print(shown)
    assert alive is not None and alive["state"] == "tracking", shown
    assert flood.answers > 0 and set(flood.statuses) == {"200"} and not flood.errors, shown
    assert figures.rss_peak_mb - figures.rss_before_mb <= RSS_GROWTH_MB, shown
    assert figures.rss_after_mb - figures.rss_before_mb <= RSS_GROWTH_MB / 2, shown  # and it returns
    assert during["frames"] > 0.5 * min(q["frames"] for q in quiet), shown  # the frame loop kept its pace
    allowed = max(q["frames_lost"] for q in quiet) + NOISE_FRACTION * during["frames"] + NOISE_FRAMES
    assert during["frames_lost"] <= allowed, shown
    assert during["grating_errors"] <= max(q["grating_errors"] for q in quiet), shown
    assert during["faults"] <= max(q["faults"] for q in quiet), shown
    assert "Traceback" not in daemon.stderr, daemon.stderr[-3000:]
