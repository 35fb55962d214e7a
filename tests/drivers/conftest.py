"""Fixtures shared by the driver tests: a simulated GCS controller on a real pty, and its driver."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from graytrack.drivers.stage.axis_model import TrapezoidAxis
from graytrack.drivers.stage.gcs_stage import GCSStage
from graytrack.drivers.stage.sim_controller import SimGCSController

# Short, so fault tests that must time out stay fast, yet long enough that a reply on a 2-core machine
# at load 8 is never taken for silence (0.15 s was: a plain ERR? timed out in CI-like load).
TIMEOUT_S = 0.5


@pytest.fixture
def timeout_s() -> float:
    return TIMEOUT_S


@pytest.fixture
def controller() -> Iterator[SimGCSController]:
    with SimGCSController(TrapezoidAxis(travel_mm=(0.0, 25.0), start_mm=12.5, velocity_mm_s=10.0)) as ctl:
        yield ctl


@pytest.fixture
def stage(controller: SimGCSController) -> Iterator[GCSStage]:
    # Opened with a generous timeout (set-up is not under test and the machine may be loaded),
    # then short, so fault tests that must time out stay fast.
    with GCSStage(controller.path, timeout_s=1.0, velocity_mm_s=20.0) as driver:
        driver.link.timeout_s = TIMEOUT_S
        yield driver
