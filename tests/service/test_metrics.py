"""``GET /metrics`` read the way Prometheus reads it: with ``prometheus_client``'s text parser.

Every family parses, has HELP and TYPE, counters end in ``_total``, no family comes or goes with
the daemon's state (starting, tracking, a stale model), every calibration outcome is there from
the first scrape, and the frame rate after an outage is the rate since the recovery. The Grafana
dashboard in deploy/ only asks for metrics the daemon exports.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families
from prometheus_client.samples import Sample

from graytrack.service.daemon import metrics
from graytrack.service.daemon.app import create_app
from graytrack.service.daemon.framerate import FrameRate
from graytrack.service.daemon.jobs import FINAL
from tests.service.helpers import GatedFactory, LiveServer, fast_settings, wait_for, wait_state

DASHBOARD = Path(__file__).resolve().parents[2] / "deploy" / "grafana-dashboard.json"


def scrape(text: str) -> dict[str, list[Sample]]:
    """The exposition's samples by family name, after checking what Prometheus needs of each family."""
    declared = dict(re.findall(r"^# TYPE (\S+) (\S+)$", text, re.M))
    helped = set(re.findall(r"^# HELP (\S+) ", text, re.M))
    assert set(declared) == helped, "every family has HELP and TYPE"
    counters = [name for name, kind in declared.items() if kind == "counter"]
    assert all(name.endswith("_total") for name in counters), f"counters without _total: {counters}"
    families = {}
    for family in text_string_to_metric_families(text):
        assert family.type in ("gauge", "counter"), f"{family.name} is {family.type}: a sample outside its family"
        assert family.documentation, f"{family.name} has no HELP"
        name = family.name + "_total" if family.type == "counter" else family.name
        assert name in declared and family.samples, f"{name}: no samples"
        assert all(sample.name == name for sample in family.samples)
        families[name] = family.samples
    assert set(families) == set(declared)
    return families


def value(families: dict[str, list[Sample]], name: str, **labels: str) -> float:
    (match,) = [s.value for s in families[name] if s.labels == labels]
    return match


# -- the text itself -----------------------------------------------------------------------------
def test_label_values_and_help_are_escaped_and_read_back_unchanged() -> None:
    awkward = 'say "hi"\\ then\nleave'
    text = "\n".join(metrics.family("graytrack_demo_total", "counter", "a \\ help\nline",
                                    [({"why": awkward}, 3), ({"why": "plain"}, None)])) + "\n"
    (family,) = text_string_to_metric_families(text)
    assert family.documentation == "a \\ help\nline"
    assert family.samples[0].labels == {"why": awkward} and family.samples[0].value == 3.0
    assert family.samples[1].value != family.samples[1].value, "None is NaN"
    assert [metrics.number(v) for v in (float("inf"), float("-inf"), True, 2)] == ["+Inf", "-Inf", "1.0", "2.0"]
    with pytest.raises(ValueError, match="graytrack_frames must end in _total"):
        metrics.family("graytrack_frames", "counter", "frames", [({}, 1)])


# -- the frame rate, on injected times -----------------------------------------------------------
def frames(rate: FrameRate, start: float, hz: float, seconds: float) -> float:
    """Arrivals at ``hz`` from ``start`` for ``seconds``; the last arrival's time."""
    n = int(round(seconds * hz))
    for k in range(n):
        rate.arrive(start + k / hz)
    return start + (n - 1) / hz


def test_the_rate_after_an_outage_is_the_rate_since_the_recovery() -> None:
    rate = FrameRate()
    last = frames(rate, 0.0, 50.0, 10.0)
    assert rate.hz(last, stale_after_s=1.0) == pytest.approx(50.0)
    assert rate.hz(last + 1.5, stale_after_s=1.0) == 0.0, "silent longer than stale_after_s"
    back = last + 5.0  # a 5 s outage, then 50 Hz again
    for seconds in (0.1, 0.5, 2.0, 3.9):
        rate = FrameRate()
        frames(rate, 0.0, 50.0, 10.0)
        newest = frames(rate, back, 50.0, seconds)
        # a window across the outage would read 21 Hz at 0.5 s (200 frames over 9.5 s)
        assert rate.hz(newest, stale_after_s=1.0) == pytest.approx(50.0), f"{seconds} s after the recovery"


def test_a_dropped_frame_or_jitter_does_not_restart_the_window_but_a_reopen_does() -> None:
    rate = FrameRate()
    for k in range(100):
        rate.arrive(k * 0.02 + (0.004 if k % 2 else 0.0))  # 50 Hz with 4 ms of jitter
    rate.arrive(99 * 0.02 + 3 * 0.02)  # two frames lost
    assert rate.hz(2.04, 1.0) == pytest.approx(100 / 2.04), "one window over 2.04 s: 101 arrivals"
    rate.arrive(2.04)  # the same frame again (a repeated exposure)
    assert rate.hz(2.04, 1.0) == pytest.approx(100 / 2.04)
    rate.restart()
    assert rate.hz(2.04, 1.0) == 0.0
    rate.arrive(2.1), rate.arrive(2.125)
    assert rate.hz(2.125, 1.0) == pytest.approx(40.0)
    with pytest.raises(ValueError, match="at least 2 arrivals"):
        FrameRate(window=1)


# -- the daemon ----------------------------------------------------------------------------------
def test_no_family_comes_or_goes_from_start_through_tracking_to_a_stale_model(tmp_path: Path) -> None:
    with LiveServer(create_app(fast_settings(tmp_path))) as daemon:
        first = scrape(daemon.get("/metrics").text)  # starting or calibrating: no position, no fit yet
        assert {s.labels["outcome"] for s in first["graytrack_calibrations_total"]} == set(FINAL)
        daemon.wait_state("tracking")
        tracking = scrape(wait_for(lambda: (t := daemon.get("/metrics").text)
                                   and 'graytrack_state{state="tracking"} 1.0' in t
                                   and "graytrack_stale 0.0" in t and "graytrack_position_meters NaN" not in t
                                   and t, what="a fresh tracked frame, placed"))
        assert set(tracking) == set(first)
        assert {s.labels["outcome"]: s.value for s in tracking["graytrack_calibrations_total"]} == {
            "done": 1.0, "failed": 0.0, "aborted": 0.0, "interrupted": 0.0}
        status = daemon.status()
        assert 0.0 <= value(tracking, "graytrack_position_meters") <= 10.46e-3
        assert 1e-8 < value(tracking, "graytrack_crlb_meters") < 1e-4, "a bound of micrometres, in meters"
        assert value(tracking, "graytrack_fit_stale") == 0.0 and value(tracking, "graytrack_locked") == 1.0
        assert value(tracking, "graytrack_frames_total") >= status["frames"] - 400  # the counter behind rate()

        model = daemon.rig.model  # a period 5 % off: it tracks, but the model no longer holds
        daemon.rig.install(model.with_changes(period_mm=model.period_mm * 1.05, coeffs=model.coeffs))
        wait_for(lambda: daemon.status()["model_stale"], 20.0, "the stale flag")
        stale = scrape(daemon.get("/metrics").text)
        assert set(stale) == set(first), "no family vanishes while the model is stale"
        assert sum(s.value for s in stale["graytrack_model_stale"]) == 1.0
        fit = [name for name in stale if name.startswith("graytrack_fit_")]
        assert sorted(fit) == sorted(name for _, name, _ in metrics.FIT_FAMILIES)


def test_jobs_found_interrupted_at_start_are_counted(tmp_path: Path) -> None:
    job = tmp_path / "calibrations" / "20240101T000000000000Z"
    job.mkdir(parents=True)
    (job / "status.json").write_text(json.dumps({"id": job.name, "state": "sweeping", "model": "paper"}))
    with TestClient(create_app(fast_settings(tmp_path, auto_calibrate="never"))) as client:
        wait_state(client, "idle")
        families = scrape(client.get("/metrics").text)
    assert {s.labels["outcome"]: s.value for s in families["graytrack_calibrations_total"]} == {
        "done": 0.0, "failed": 0.0, "aborted": 0.0, "interrupted": 1.0}


def test_the_frame_rate_after_a_camera_outage_is_not_dragged_down_by_it(tmp_path: Path) -> None:
    factory = GatedFactory()
    with TestClient(create_app(fast_settings(tmp_path), factory)) as client:
        wait_state(client, "tracking", 20.0)
        before = wait_for(lambda: client.get("/api/status").json()["frame_rate_hz"], what="a frame rate")
        factory.hardware.camera.gate_open = False  # 1.5 s without a frame (200 frames/s before)
        wait_state(client, "fault")
        wait_for(lambda: client.app.state.rig.acquisition.seconds_since_frame() > 1.5, what="a 1.5 s outage")
        factory.hardware.camera.gate_open = True
        wait_for(lambda: client.app.state.rig.acquisition.seconds_since_frame() < 0.1, what="frames again")
        time.sleep(0.3)  # 60 frames since the recovery
        after = scrape(client.get("/metrics").text)
    # a 200-frame window across the outage would read 60 frames over 2.4 s plus 140 before: ~80 /s
    assert value(after, "graytrack_frame_rate_hertz") == pytest.approx(before, rel=0.3)


# -- the dashboard -------------------------------------------------------------------------------
def expressions(panels: list[dict]) -> list[str]:
    found = []
    for panel in panels:
        found += [target["expr"] for target in panel.get("targets", [])]
        found += expressions(panel.get("panels", []))  # rows hold panels
    return found


def test_the_grafana_dashboard_asks_only_for_exported_metrics(tmp_path: Path) -> None:
    dashboard = json.loads(DASHBOARD.read_text())
    assert dashboard["schemaVersion"] >= 39 and dashboard["panels"]
    exprs = expressions(dashboard["panels"]) + [v["query"] for v in dashboard["templating"]["list"]
                                                 if v["type"] == "query"]
    used = {name for expr in exprs for name in re.findall(r"\bgraytrack_[a-z0-9_]+", expr)}
    with TestClient(create_app(fast_settings(tmp_path, auto_calibrate="never"))) as client:
        wait_state(client, "idle")
        exported = set(scrape(client.get("/metrics").text))
    assert used and used <= exported, f"not exported: {sorted(used - exported)}"
    wanted = {"graytrack_position_meters", "graytrack_crlb_meters", "graytrack_locked", "graytrack_stale",
              "graytrack_model_stale", "graytrack_frames_total", "graytrack_frames_dropped_total",
              "graytrack_faults_total", "graytrack_calibrations_total"}
    assert wanted <= used, f"panels missing for {sorted(wanted - used)}"
    assert any("rate(graytrack_frames_total" in expr for expr in exprs), "the frame rate is rate() of the counter"
