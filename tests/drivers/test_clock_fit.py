"""The device-to-host clock fit on synthetic frames with known offset, drift and delivery delays."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.drivers.camera.clock_fit import DeviceClockFit

OFFSET_S, DRIFT, BASE_DELAY_S = 5_000.25, 40e-6, 150e-6  # host = offset + (1 + drift) * device + delay


def deliveries(n: int, rate_hz: float = 1000.0, seed: int = 0, late_fraction: float = 0.05):
    """Device stamps (ns, from an arbitrary large origin), the true host event times, host arrivals."""
    rng = np.random.default_rng(seed)
    device_ns = 7_000_000_000_000 + np.arange(n, dtype=np.int64) * int(1e9 / rate_hz)
    event = OFFSET_S + (1 + DRIFT) * (device_ns - device_ns[0]) * 1e-9
    delay = BASE_DELAY_S + rng.exponential(100e-6, n)
    late = rng.random(n) < late_fraction
    delay[late] += rng.uniform(2e-3, 30e-3, late.sum())  # scheduler stalls, backlog
    return device_ns, event, event + delay


@pytest.mark.parametrize(("rate_hz", "bound_us"), [(1000.0, 3.0), (50.0, 25.0)])
def test_envelope_removes_jitter_late_deliveries_and_drift(rate_hz: float, bound_us: float) -> None:
    device_ns, event, arrival = deliveries(int(10 * rate_hz), rate_hz)
    fit = DeviceClockFit()
    mapped = []
    for d, h in zip(device_ns, arrival):
        fit.add(int(d), float(h))
        mapped.append(fit.host_time(int(d)))
    settled = slice(int(2 * rate_hz), None)  # once the fit has 16 bins (1.6 s)
    error = (np.array(mapped) - (event + BASE_DELAY_S))[settled]  # the envelope is the earliest arrival
    naive = (arrival - event - BASE_DELAY_S)[settled]  # stamping frames with their arrival
    assert np.max(np.abs(error)) < bound_us * 1e-6, np.max(np.abs(error))
    assert np.percentile(np.abs(naive), 99) > 100 * np.percentile(np.abs(error), 99)
    assert fit.established and fit.rate == pytest.approx(1 + DRIFT, abs=3e-6)
    assert fit.spread_s < bound_us * 1e-6 and fit.restarts == 0 and fit.n_bins == 64


def test_first_frames_map_onto_the_earliest_arrival_seen() -> None:
    fit = DeviceClockFit()
    with pytest.raises(ValueError):
        fit.host_time(0)
    fit.add(1_000_000_000, 10.0)
    assert fit.host_time(1_000_000_000) == 10.0
    assert fit.host_time(1_010_000_000) == pytest.approx(10.01)
    fit.add(1_010_000_000, 10.020)  # 10 ms late
    fit.add(1_020_000_000, 10.0201)
    assert fit.host_time(1_010_000_000) <= 10.0101 + 1e-9, "a late arrival does not pull the line up"


def test_device_clock_reset_or_long_gap_restarts_the_fit() -> None:
    device_ns, _, arrival = deliveries(200, late_fraction=0.0)
    fit = DeviceClockFit()
    for d, h in zip(device_ns, arrival):
        fit.add(int(d), float(h))
    fit.add(5, float(arrival[-1] + 0.5))  # the camera rebooted: its counter starts over
    assert fit.restarts == 1 and fit.n_bins == 1
    assert fit.host_time(5) == pytest.approx(arrival[-1] + 0.5)
    fit.add(5 + 60 * 10**9, float(arrival[-1] + 60.5))  # a minute without frames
    assert fit.restarts == 2
