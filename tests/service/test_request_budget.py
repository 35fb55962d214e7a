"""The request budget and the per-client count (service/daemon/limits.py) on an injected clock."""

from __future__ import annotations

import pytest

from graytrack.service.daemon.limits import ConnectionLimits, RequestBudget, client_key
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
