"""One contract, every stage: the GCS driver over a real pty against the simulated controller with
a plain trapezoid axis, and the virtual rig's stage as the daemon builds it (the rig's physics on
a simulated clock running 5x wall time, its grating readout behind the same controller). The
tests are the same: readings stamped on the host's ``time.monotonic`` at the middle of the
request and the reply, moves and settling, soft limits enforced before anything is sent, stop,
timeouts, close and reopen.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from graytrack.drivers.clock import ScaledClock
from graytrack.drivers.config import parse_hardware
from graytrack.drivers.factory import open_hardware
from graytrack.drivers.stage.axis_model import TrapezoidAxis
from graytrack.drivers.stage.base import Stage
from graytrack.drivers.stage.errors import StageLimitError, StageTimeoutError
from graytrack.drivers.stage.gcs_stage import GCSStage
from graytrack.drivers.stage.sim_controller import Fault, SimGCSController

REPLY_TIMEOUT_S = 1.0  # generous: the suite shares two cores with everything else
MUTE_TIMEOUT_S = 0.15  # short, so the timeout test stays fast


@dataclass
class Case:
    stage: Stage
    controller: SimGCSController
    start_mm: float
    limits_mm: tuple[float, float]
    long_move_mm: float  # a target far enough that the move lasts a while
    tolerance_mm: float  # settled reading against the target (grating resolution)


@pytest.fixture(params=["gcs-trapezoid", "virtual-rig"])
def case(request: pytest.FixtureRequest) -> Iterator[Case]:
    if request.param == "gcs-trapezoid":
        with SimGCSController(TrapezoidAxis(travel_mm=(0.0, 25.0), start_mm=12.5, velocity_mm_s=10.0)) as ctl:
            with GCSStage(ctl.path, timeout_s=REPLY_TIMEOUT_S, velocity_mm_s=20.0, soft_limits_mm=(5.0, 20.0)) as stage:
                yield Case(stage, ctl, 12.5, (5.0, 20.0), 19.5, 1e-9)
        return
    config = parse_hardware({"stage": {"velocity_mm_s": 4.0, "timeout_s": REPLY_TIMEOUT_S,
                                       "soft_limits_mm": [0.0, 10.0]},
                             # in process: the test injects faults into its controller
                             "camera": {"rig_process": False}})
    hardware = open_hardware(config, ScaledClock(5.0))
    try:
        start = hardware.stage.position().position_mm
        yield Case(hardware.stage, hardware.controller, start, (0.0, 10.0), 9.5, 1e-3)  # type: ignore[arg-type]
    finally:
        hardware.close()


def test_readings_are_stamped_mid_transaction_on_the_host_monotonic_clock(case: Case) -> None:
    stage = case.stage
    stage.move_to(case.long_move_mm)
    readings = []
    for _ in range(6):
        before = time.monotonic()
        reading = stage.position()
        after = time.monotonic()
        assert before <= reading.t <= after and 0 <= reading.latency_s <= after - before
        assert reading.t == pytest.approx(before + 0.5 * (after - before), abs=0.5 * (after - before))
        readings.append(reading)
    stage.stop()
    positions = [r.position_mm for r in readings]
    assert positions == sorted(positions) and positions[-1] > positions[0], "sampled while moving up"
    assert all(b.t > a.t for a, b in zip(readings, readings[1:]))


def test_moves_settle_on_target_and_relative_moves_add(case: Case) -> None:
    stage = case.stage
    low, high = case.limits_mm
    target = low + 0.3 * (high - low)
    stage.move_to(target)
    assert stage.wait_on_target(5.0).position_mm == pytest.approx(target, abs=case.tolerance_mm)
    assert stage.on_target()
    stage.move_by(0.25)
    assert stage.wait_on_target(5.0).position_mm == pytest.approx(target + 0.25, abs=case.tolerance_mm)


def test_soft_limits_refuse_moves_before_anything_is_sent(case: Case) -> None:
    stage, controller = case.stage, case.controller
    low, high = case.limits_mm
    assert stage.limits() == (low, high)
    sent = len(controller.received)
    for bad in (high + 0.5, low - 0.5, math.nan, math.inf):
        with pytest.raises(StageLimitError):
            stage.move_to(bad)
    with pytest.raises(StageLimitError):
        stage.move_by(-(case.start_mm - low) - 0.5)
    assert not any(line.startswith(("MOV ", "MVR ")) for line in list(controller.received)[sent:])
    assert stage.position().position_mm == pytest.approx(case.start_mm, abs=case.tolerance_mm)


def test_stop_comes_to_rest_short_of_the_target_and_stays(case: Case) -> None:
    stage = case.stage
    stage.move_to(case.long_move_mm)
    time.sleep(0.05)
    stage.stop()  # abrupt on the trapezoid axis, decelerating on the rig's servo model
    stopped_at = stage.wait_on_target(5.0).position_mm
    assert case.start_mm < stopped_at < case.long_move_mm
    time.sleep(0.05)
    assert stage.position().position_mm == pytest.approx(stopped_at, abs=case.tolerance_mm)


def test_a_mute_controller_gives_a_timeout_error_in_bounded_time(case: Case) -> None:
    case.stage.link.timeout_s = MUTE_TIMEOUT_S  # type: ignore[attr-defined]
    case.controller.inject(Fault("drop", count=10))
    start = time.monotonic()
    with pytest.raises(StageTimeoutError, match=r"no reply to 'POS\? 1'"):
        case.stage.position()
    assert time.monotonic() - start < 4 * MUTE_TIMEOUT_S + 0.2


def test_close_then_reopen_finds_the_axis_where_it_was(case: Case) -> None:
    stage = case.stage
    low, high = case.limits_mm
    target = low + 0.6 * (high - low)
    stage.move_to(target)
    stage.wait_on_target(5.0)
    stage.close()
    stage.close()  # twice is harmless
    stage.open()
    reading = stage.position()
    assert reading.position_mm == pytest.approx(target, abs=case.tolerance_mm)
    assert reading.t <= time.monotonic()
