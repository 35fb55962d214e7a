"""The request budget, serving's share of a core and the per-client count (service/daemon/limits.py), on an
injected clock."""

from __future__ import annotations

import threading
import time

import pytest

from graytrack.service.daemon.limits import (WORKER_THREAD, ConnectionLimits, RequestBudget, ServingCpu,
                                             ServingShare, client_key)
from graytrack.service.daemon.settings import DaemonConfig

pytestmark = pytest.mark.unit


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_client_gets_a_seconds_worth_at_once_then_its_turns_at_its_rate() -> None:
    clock = Clock()
    budget = RequestBudget(per_client_hz=8.0, total_hz=1000.0, burst_s=1.0, monotonic=clock)
    assert [budget.take("a") for _ in range(8)] == [0.0] * 8
    # each further request has its token lent and waits its turn, once (no retry, no crowd at each refill)
    assert [budget.take("a") for _ in range(3)] == [0.125, 0.25, 0.375]
    assert budget.take("b") == 0.0, "another client has its own bucket"
    clock.now += 0.375  # the three waiting ones went
    assert budget.take("a") == 0.125
    clock.now += 60
    assert [budget.take("a") for _ in range(9)].count(0.0) == 8, "refilled to a second's worth, no more"


def test_a_token_lent_and_never_used_is_given_back() -> None:
    """A client that connects, asks and closes while it waits, again and again, must not run up a debt that
    every other client then waits for."""
    clock = Clock()
    budget = RequestBudget(per_client_hz=8.0, total_hz=8.0, burst_s=1.0, monotonic=clock)
    for _ in range(8):
        budget.take("a")
    for _ in range(1000):
        assert budget.take("a") == 0.125
        budget.give_back("a")
    clock.now += 0.125
    assert budget.take("b") == 0.0


def test_all_clients_together_share_the_total() -> None:
    clock = Clock()
    budget = RequestBudget(per_client_hz=100.0, total_hz=16.0, burst_s=1.0, monotonic=clock)
    waits = [budget.take(f"client{i % 4}") for i in range(20)]
    assert waits[:16] == [0.0] * 16 and waits[16:] == [0.0625, 0.125, 0.1875, 0.25]


def test_full_buckets_are_forgotten_beyond_the_tracked_clients(monkeypatch: pytest.MonkeyPatch) -> None:
    from graytrack.service.daemon import limits

    monkeypatch.setattr(limits, "MAX_TRACKED_CLIENTS", 3)
    clock = Clock()
    budget = RequestBudget(per_client_hz=10.0, total_hz=1e6, burst_s=1.0, monotonic=clock)
    for key in "abc":
        budget.take(key)
    clock.now += 1.0  # a, b and c full again
    budget.take("d")
    budget.take("e")
    assert set(budget._clients) == {"d", "e"}


@pytest.mark.parametrize("address, key", [(("192.0.2.7", 5000), "192.0.2.7"), (None, "local"),
                                          (("2001:db8:1:2:aa::1", 5000), "2001:db8:1:2::/64"),
                                          (("2001:db8:1:2:bb::9", 5001), "2001:db8:1:2::/64"),
                                          (("::ffff:192.0.2.7", 5000), "192.0.2.7"), (("::1", 5000), "::1")])
def test_a_client_is_its_address_and_an_ipv6_one_its_64(address, key) -> None:
    assert client_key(address) == key


def test_connections_are_counted_per_client_until_released() -> None:
    """As each connection opens (the protocol asks then), with the client's count including it."""
    limits = ConnectionLimits(DaemonConfig(max_connections=100, max_connections_per_client=2))
    verdicts = []
    for port in range(1, 6):
        ticket = limits.admit(("192.0.2.7", port))
        verdicts.append((limits.over(port, ticket), limits.beyond_hard_cap(port, ticket)))
    assert [v[0] is None for v in verdicts] == [True, True, False, False, False]
    assert "at most 2 connections from one client" in (verdicts[2][0] or "")
    assert [v[1] for v in verdicts] == [False, False, False, False, True], "beyond twice its share: closed at once"
    other = limits.admit(("192.0.2.8", 1))
    assert limits.over(6, other) is None, "another client is served"
    assert "[daemon] max_connections)" in (limits.over(101, other) or "")
    other.release()
    other.release()  # once only
    assert limits.admit(("192.0.2.8", 2)).client_connections == 1


class Cpu:
    """Serving's CPU seconds, advanced by hand."""

    def __init__(self) -> None:
        self.used = 5.0

    def __call__(self) -> float:
        return self.used


def test_serving_beyond_its_share_makes_the_next_requests_wait_one_after_another() -> None:
    """Requests cost what they are measured to cost: a quarter of a core holds 0.25 s of CPU at once; spent,
    the waiting requests go in turn, a mean request's cost apart, never all at the same refill."""
    clock, cpu = Clock(), Cpu()
    share = ServingShare(0.25, 1.0, cpu, clock)
    waits = []
    for _ in range(16):  # 16 requests of 20 ms within a second: the first window measures their cost
        waits.append(share.take())
        cpu.used += 0.02
        clock.now += 0.01
    # 17.5 ms of the bucket each (20 ms used, 2.5 ms refilled): the 16th finds it empty
    assert waits[:15] == [0.0] * 15 and waits[15] > 0
    assert share.cost_s == pytest.approx(0.02, rel=0.1)
    level_waits = [share.take() for _ in range(3)]  # three more at once, nothing measured between them
    assert level_waits[1] - level_waits[0] == pytest.approx(share.cost_s / 0.25)
    assert level_waits[2] - level_waits[1] == pytest.approx(share.cost_s / 0.25)


def test_cpu_charged_for_a_request_that_never_ran_is_given_back_by_the_measurement() -> None:
    clock, cpu = Clock(), Cpu()
    share = ServingShare(0.25, 1.0, cpu, clock)
    assert share.take() == 0.0  # (the first request: where serving's CPU is measured from)
    cpu.used += 0.5  # serving overspent by a quarter second: in debt
    assert share.take() > 0
    clock.now += 1.01
    # the waiting request's connection closed: nothing ran, so nothing was used
    assert share.take() == 0.0, "a second at a quarter pays 0.25 s of debt, and the charge comes back"


def test_a_debt_never_holds_a_request_longer_than_a_burst() -> None:
    """A cost that is not the requests' (a collection, a thread's end counted at once) is bounded."""
    clock, cpu = Clock(), Cpu()
    share = ServingShare(0.25, 1.0, cpu, clock)
    share.take()
    cpu.used += 30.0
    assert share.take() <= 1.0 + share.cost_s / 0.25 + 1e-9


def test_a_quiet_daemon_answers_at_once_whatever_the_share() -> None:
    clock, cpu = Clock(), Cpu()
    share = ServingShare(0.05, 1.0, cpu, clock)
    for _ in range(50):  # a page polling every 100 ms, 1 ms per answer: 1 % of a core
        assert share.take() == 0.0
        cpu.used += 0.001
        clock.now += 0.1


def test_serving_counts_the_loop_and_the_request_threads_and_keeps_what_an_ended_one_used() -> None:
    """The threads that answer requests are anyio's workers (FastAPI runs sync endpoints there) and the loop (here
    the test's own thread, the first to ask); any other thread of the process (the rig's, a test's own clients) is
    not serving's."""
    cpu = ServingCpu()
    before, loop_before = cpu(), time.thread_time()

    def spin(seconds: float) -> None:
        end = time.thread_time() + seconds
        while time.thread_time() < end:
            pass

    other = threading.Thread(target=spin, args=(0.1,), name="rig")
    other.start()
    other.join()
    assert cpu() - before - (time.thread_time() - loop_before) < 0.01, "another thread's CPU is not serving's"
    worker = threading.Thread(target=spin, args=(0.05,), name=WORKER_THREAD)
    worker.start()
    while worker.is_alive():  # read while it runs, then after it has gone
        cpu()
        time.sleep(0.001)
    worker.join()
    workers = cpu() - before - (time.thread_time() - loop_before)
    assert 0.04 <= workers < 0.1, "a worker's CPU counted, and kept after it ended"


def test_a_frame_the_rig_loses_cuts_servings_share_and_it_grows_back() -> None:
    """The rig first: serving's share is what it may take where the frame loop has room; a frame lost while
    serving has it halves the share in force at once (the bucket emptied), to an eighth at least, and a quiet
    stretch gives it back."""
    clock, cpu, lost = Clock(), Cpu(), [0]  # (frames the rig lost so far)
    share = ServingShare(0.25, 1.0, cpu, clock, lambda: lost[0])
    assert share.take() == 0.0
    assert share.share == 0.25
    lost[0] += 3  # the frame loop fell behind
    clock.now += 0.01
    wait = share.take()
    assert share.share == pytest.approx(0.125) and share.cuts == 1
    assert wait == pytest.approx(share.cost_s / 0.125), "the bucket was emptied: the next request waits its cost"
    for _ in range(5):  # a loss at every request: the share falls to its floor, not to nought
        lost[0] += 1
        share.take()
    assert share.share == pytest.approx(0.25 * 0.125) and share.cuts == 6
    clock.now += 5.0  # half the recovery time without a loss
    share.take()
    assert share.share == pytest.approx(0.25 * (0.125 + 0.5))
    clock.now += 60.0
    share.take()
    assert share.share == 0.25, "whole again, never above what was declared"


def test_a_new_frame_loop_counting_from_nought_is_no_loss() -> None:
    clock, cpu, lost = Clock(), Cpu(), [40]
    share = ServingShare(0.25, 1.0, cpu, clock, lambda: lost[0])
    lost[0] = 0  # the camera reopened: a new frame loop
    share.take()
    share.take()
    assert share.share == 0.25 and share.cuts == 0
