"""Pipelined requests against a real ``graytrack serve`` (issue #48, service/daemon/limits.py): ten
connections writing ``GET /api/status`` 100 at a time without waiting, reading what comes back, against a
quiet window of the same length just before, on the same daemon. Before the protocol parsed one request
at a time, this grew the daemon by hundreds of MB (kept after close) and the frame loop lost a large part
of its frames; bench/pipeline_flood.py prints the same figures over 20 s.

Marked ``alone``: the frame loop's losses follow the host's load, so the flood and its quiet window need
the machine to themselves (make test runs these after the rest, serially).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.service.helpers import ServeProcess
from tests.service.hostile import quiet_then_flood

pytestmark = pytest.mark.alone

FLOOD_S = 8.0  # the claim holds from the first seconds (the old code had grown by 200+ MB by then)
CONNECTIONS = 10
RSS_GROWTH_MB = 40.0  # issue #48's acceptance
# Frames lost to the host's load in one window of FLOOD_S on a busy machine: the flood's may differ from the
# quiet window's by this many (plus 1 % of the frames) without any doing of the flood.
NOISE_FRAMES = 5


def test_a_pipelined_flood_leaves_memory_flat_and_the_rig_untouched(tmp_path: Path) -> None:
    # the virtual rig in a process of its own, as the daemon runs it by default: the daemon's interpreter holds
    # the frame loop and the stage link, which the flood must not reach
    with ServeProcess(tmp_path, camera={"rig_process": True}) as daemon:
        daemon.wait_state("tracking", timeout_s=120)
        figures = quiet_then_flood(daemon.base, daemon.process.pid, daemon.port, FLOOD_S, CONNECTIONS)
        alive = daemon.status()
        assert daemon.terminate() == 0
    flood, quiet, during = figures.client, figures.quiet, figures.flood
    shown = (f"RSS {figures.rss_before_mb:.0f} -> peak {figures.rss_peak_mb:.0f} -> {figures.rss_after_mb:.0f} MB; "
             f"quiet {quiet}; flood {during}; {flood.answers} answers {flood.statuses}, errors {flood.errors[:3]}")
    print(shown)
    assert alive is not None and alive["state"] == "tracking", shown
    assert flood.answers > 0 and set(flood.statuses) == {"200"} and not flood.errors, shown
    assert figures.rss_peak_mb - figures.rss_before_mb <= RSS_GROWTH_MB, shown
    assert figures.rss_after_mb - figures.rss_before_mb <= RSS_GROWTH_MB / 2, shown  # and it returns
    assert during["frames"] > 0.5 * quiet["frames"], shown  # the frame loop kept its pace
    allowed = quiet["frames_lost"] + NOISE_FRAMES + 0.01 * quiet["frames"]
    assert during["frames_lost"] <= allowed, shown
    assert during["grating_errors"] <= quiet["grating_errors"] and during["faults"] <= quiet["faults"], shown
    assert "Traceback" not in daemon.stderr, daemon.stderr[-3000:]
