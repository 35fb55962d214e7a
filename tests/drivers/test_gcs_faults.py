"""Fault injection: line noise, cut and lost replies, late replies, a port that vanishes.

The property that matters: the driver either returns the right answer to the command it sent or
raises a typed StageError, never a value that belongs to another command, and it recovers on
the next call without anyone restarting it.
"""

from __future__ import annotations

import random
import threading
import time

import pytest

from graytrack.drivers.stage.errors import StageConnectionError, StageError, StageTimeoutError
from graytrack.drivers.stage.gcs_stage import GCSStage
from graytrack.drivers.stage.sim_controller import Fault, SimGCSController


@pytest.mark.parametrize(
    "payload",
    [b"\xff\xfe#~\x00", b"\x13garbage line\n", b"1=99.0 \n", None],
    ids=["glued-noise", "own-line", "fake-continuation", "random"],
)
def test_noise_before_a_reply_is_survived_with_the_right_value(
    controller: SimGCSController, stage: GCSStage, payload: bytes | None
) -> None:
    controller.inject(Fault("garbage", command="VEL?", payload=payload))
    assert stage.velocity() == 20.0
    assert stage.link.stats.malformed == 1 and stage.link.stats.resyncs >= 1
    assert stage.travel_range() == (0.0, 25.0)


def test_partial_reply_times_out_and_its_tail_is_never_read_as_the_next_answer(
    controller: SimGCSController, stage: GCSStage
) -> None:
    controller.inject(Fault("partial", command="TMN?"))
    with pytest.raises(StageTimeoutError, match="TMN"):
        stage.travel_range()
    assert stage.velocity() == 20.0
    assert stage.travel_range() == (0.0, 25.0)


def test_late_reply_is_discarded_not_paired_with_the_next_command(
    controller: SimGCSController, stage: GCSStage, timeout_s: float
) -> None:
    controller.inject(Fault("slow", command="MOV?", delay_s=1.5 * timeout_s))
    with pytest.raises(StageTimeoutError):
        stage.target()  # replies 12.5, too late
    assert stage.velocity() == 20.0
    assert stage.target() == 12.5
    # a slow reply inside the timeout is simply slow
    controller.inject(Fault("slow", command="VEL?", delay_s=0.5 * timeout_s))
    assert stage.velocity() == 20.0


def test_dropped_reply_to_err_query_never_loses_the_link(controller: SimGCSController, stage: GCSStage) -> None:
    controller.inject(Fault("drop", command="ERR?"))
    with pytest.raises(StageTimeoutError, match="ERR"):
        stage.move_to(13.0)
    assert stage.wait_on_target(1.0).position_mm == pytest.approx(13.0, abs=1e-9)


def test_fault_storm_never_pairs_a_reply_with_the_wrong_command(
    controller: SimGCSController, stage: GCSStage, timeout_s: float
) -> None:
    rng = random.Random(7)
    expected = {
        "TMN?": (stage.travel_min, 0.0),
        "TMX?": (stage.travel_max, 25.0),
        "VEL?": (stage.velocity, 20.0),
        "MOV?": (stage.target, 12.5),
        "POS?": (lambda: stage.position().position_mm, 12.5),
    }
    faults = [
        lambda name: Fault("garbage", command=name),
        lambda name: Fault("garbage", command=name, payload=b"1=7.0\n"),
        lambda name: Fault("partial", command=name),
        lambda name: Fault("drop", command=name),
        lambda name: Fault("slow", command=name, delay_s=1.3 * timeout_s),
    ]
    answered = raised = 0
    for _ in range(24):
        name = rng.choice(sorted(expected))
        if rng.random() < 0.5:
            controller.inject(rng.choice(faults)(name))
        call, value = expected[name]
        try:
            got = call()
        except StageError:
            raised += 1
            continue
        answered += 1
        assert got == value, f"{name} answered {got!r}"
    assert answered >= 14 and raised >= 2
    for name, (call, value) in expected.items():
        assert call() == value, name


def test_driver_reconnects_within_two_seconds_after_the_port_returns(
    controller: SimGCSController, stage: GCSStage
) -> None:
    stage.move_to(15.0)
    stage.wait_on_target(1.0)
    controller.vanish()
    with pytest.raises(StageConnectionError):
        stage.position()
    with pytest.raises(StageConnectionError, match="cannot open"):
        stage.position()
    time.sleep(0.2)
    controller.reappear()
    returned = time.monotonic()
    while True:  # the caller just keeps polling, as the acquisition loop does
        try:
            reading = stage.position()
            break
        except StageConnectionError:
            assert time.monotonic() - returned < 2.0, "no reconnection within 2 s"
            time.sleep(0.01)
    assert time.monotonic() - returned < 2.0
    assert reading.position_mm == pytest.approx(15.0, abs=1e-9), "controller state survived the replug"
    assert stage.link.stats.reconnects == 1
    stage.move_to(16.0)  # and it is fully usable
    assert stage.wait_on_target(1.0).position_mm == pytest.approx(16.0, abs=1e-9)


def test_port_vanishing_in_the_middle_of_a_reply_raises_connection_error(
    controller: SimGCSController, stage: GCSStage
) -> None:
    controller.inject(Fault("slow", command="POS?", delay_s=0.1))
    vanisher = threading.Timer(0.03, controller.vanish)
    vanisher.start()
    with pytest.raises(StageConnectionError):
        stage.position()
    vanisher.join()
    controller.reappear()
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        try:
            assert stage.velocity() == 20.0
            return
        except StageConnectionError:
            time.sleep(0.01)
    pytest.fail("no reconnection within 2 s")
