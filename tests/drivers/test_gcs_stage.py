"""The GCS driver against the simulated controller through a real pty opened by pyserial."""

from __future__ import annotations

import threading
import time

import pytest

from graytrack.drivers.stage.axis_model import TrapezoidAxis
from graytrack.drivers.stage.errors import GCSControllerError, StageLimitError
from graytrack.drivers.stage.gcs_stage import GCSStage
from graytrack.drivers.stage.sim_controller import Fault, SimGCSController


def test_open_identifies_switches_servo_on_references_and_sets_velocity(
    controller: SimGCSController, stage: GCSStage
) -> None:
    assert "Physik Instrumente" in stage.identify()
    assert stage.servo_on() and stage.is_referenced()
    assert stage.velocity() == 20.0
    assert stage.limits() == (0.0, 25.0)
    assert list(controller.received)[:2] == ["*IDN?", "SVO? 1"]
    assert "SVO 1 1" in controller.received and "FRF 1" in controller.received


def test_controller_errors_carry_gcs_number_and_text(controller: SimGCSController, stage: GCSStage) -> None:
    with pytest.raises(StageLimitError, match="beyond the controller's limit of 50 mm/s"):
        stage.set_velocity(500.0)  # GCS error 8 on VEL: named with the limit the controller gives (SPA? 0xA)
    assert stage.velocity_limit() == 50.0 and stage.error_code() == 0
    with pytest.raises(StageLimitError, match="below the 1e-9 mm/s"):
        stage.set_velocity(1e-12)  # would go out as "VEL 1 0.0"
    controller.inject(Fault("error", command="MOV", code=7))
    with pytest.raises(GCSControllerError, match="GCS error 7 .target position out of limits.") as err:
        stage.move_to(13.0)
    assert err.value.code == 7
    assert stage.error_code() == 0, "ERR? after the command has already cleared the register"
    stage.move_to(13.0)  # the link and controller are fine afterwards
    assert stage.wait_on_target(1.0).position_mm == pytest.approx(13.0, abs=1e-9)


def test_move_without_reference_raises_error_5(controller: SimGCSController, timeout_s: float) -> None:
    with GCSStage(controller.path, timeout_s=timeout_s, reference_on_open=False) as stage:
        assert not stage.is_referenced()
        with pytest.raises(GCSControllerError) as err:
            stage.move_to(10.0)
        assert err.value.code == 5


def test_query_the_controller_refuses_raises_its_error_not_a_bare_timeout(stage: GCSStage) -> None:
    stage.axis = "2"  # the controller has one axis; a query for another gets silence + error 15
    with pytest.raises(GCSControllerError) as err:
        stage.on_target()
    assert err.value.code == 15
    stage.axis = "1"
    assert stage.on_target() in (True, False)


def test_stop_and_halt_swallow_only_their_own_error_10(controller: SimGCSController, stage: GCSStage) -> None:
    stage.move_to(24.0)
    time.sleep(0.05)
    stage.stop()
    assert stage.error_code() == 0
    stage.move_to(20.0)
    stage.halt()
    assert stage.error_code() == 0


def test_multi_line_replies_are_framed_as_one_reply(stage: GCSStage) -> None:
    lines, _ = stage.link.query("HLP?")
    assert len(lines) > 10 and any(line.startswith("POS?") for line in lines)
    assert stage.velocity() == 20.0, "the next transaction is not disturbed by the long reply"


def test_concurrent_callers_never_get_each_others_replies(stage: GCSStage) -> None:
    stage.move_to(13.0)
    stage.wait_on_target(1.0)
    expected = {"velocity": 20.0, "target": 13.0, "travel": (0.0, 25.0), "position": 13.0}
    calls = {
        "velocity": stage.velocity,
        "target": stage.target,
        "travel": stage.travel_range,
        "position": lambda: stage.position().position_mm,
    }
    failures: list[str] = []

    def worker(name: str) -> None:
        for _ in range(40):
            value = calls[name]()
            if value != expected[name]:
                failures.append(f"{name}: {value!r}")

    threads = [threading.Thread(target=worker, args=(name,)) for name in calls]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert failures == []
    assert stage.link.stats.malformed == 0 and stage.link.stats.resyncs == 0


def test_unknown_controller_model_is_accepted_with_its_own_idn(timeout_s: float) -> None:
    with SimGCSController(TrapezoidAxis(), idn="(c)2020 PI, E-873.1AT, 1, 2") as ctl:
        with GCSStage(ctl.path, timeout_s=timeout_s) as stage:
            assert stage.identify() == "(c)2020 PI, E-873.1AT, 1, 2"


def test_command_log_is_bounded_so_memory_stays_flat() -> None:
    with SimGCSController(TrapezoidAxis(), keep_received=50) as ctl:
        with GCSStage(ctl.path, timeout_s=1.0) as stage:
            for _ in range(120):
                stage.position()
            assert len(ctl.received) == 50, "only the newest lines are kept"
            assert list(ctl.received)[-1] == "POS? 1" and "*IDN?" not in ctl.received
