"""Fixtures shared by the driver tests: a simulated GCS controller on a real pty, and its driver."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from graytrack.drivers.stage.axis_model import TrapezoidAxis
from graytrack.drivers.stage.gcs_stage import GCSStage
from graytrack.drivers.stage.sim_controller import SimGCSController

TIMEOUT_S = 0.15  # short, so fault tests that must time out stay fast


@pytest.fixture
def timeout_s() -> float:
    return TIMEOUT_S


@pytest.fixture
def controller() -> Iterator[SimGCSController]:
    with SimGCSController(TrapezoidAxis(travel_mm=(0.0, 25.0), start_mm=12.5, velocity_mm_s=10.0)) as ctl:
        yield ctl


@pytest.fixture
def stage(controller: SimGCSController) -> Iterator[GCSStage]:
    with GCSStage(controller.path, timeout_s=TIMEOUT_S, velocity_mm_s=20.0) as driver:
        yield driver
