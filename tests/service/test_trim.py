"""The daemon's camera-against-grating watch and online trim: on evidence only, shown, reversible."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from fastapi.testclient import TestClient

from graytrack.core.models.fourier import FourierModel
from graytrack.core.reference_monitor import MIN_FRAMES
from graytrack.core.tracking import LiveFix
from graytrack.core.validity import FrameSign
from graytrack.service.daemon.acquisition import fix_message
from graytrack.service.daemon.app import create_app
from graytrack.service.daemon.trim import ReferenceTrim
from tests.service.helpers import fast_settings, wait_for, wait_state


def _stroke_model() -> FourierModel:
    """A sine print over a 10 mm stroke: what the monitor needs of a model, and the watches the trim carries
    (magnification, grating) and the untrimmed watch (the far-off judgement: its calibrated bound 0.5 µm)."""
    model = FourierModel(1.0, 0.06, 100, harmonics=1, pixel_degree=0, stroke_range_mm=(0.0, 10.0))
    coefficients = np.zeros(model.coeff_shape)
    coefficients[0, 0], coefficients[1, 0] = 100.0, 30.0
    return model.with_changes(coeffs=coefficients, noise_gray=0.7)


STROKE = _stroke_model()
BOUND_MM = 1.5e-3


def _frames(n: int, offset_um: float, scale_ppm: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    ref = 5.0 + 4.0 * np.sin(np.arange(n) / 40.0)  # the stage going to and fro
    x = ref + (offset_um + scale_ppm * 1e-3 * (ref - 5.0) + rng.normal(0, BOUND_MM * 1e3, n)) * 1e-3
    return x, ref


class _Live:
    """The daemon's hand-off without a camera: the trim's watch, as the tracker's monitor feeds it
    (one sign per frame), then the trim's ``apply`` on the frame's fix."""

    def __init__(self, trim: ReferenceTrim) -> None:
        self.trim = trim
        self.install()

    def install(self) -> None:
        self.watch = self.trim.watch_for(STROKE)
        self.trim.install(STROKE, self.watch)

    def feed(self, x, ref) -> tuple[list[LiveFix], list[str | None]]:
        fixes, flags = [], []
        for xi, ri in zip(x, ref):
            flags.append(self.watch.observe(FrameSign(0, information=BOUND_MM ** -2, x_mm=xi, reference_mm=ri)))
            fixes.append(self.trim.apply(LiveFix(xi, True, 0.7, BOUND_MM, None), ri))
        return fixes, flags


def _feed(live: _Live, x, ref) -> list[LiveFix]:
    return live.feed(x, ref)[0]


def test_without_the_setting_a_drift_is_an_event_and_the_positions_are_left_alone():
    events: list[tuple[str, str]] = []
    trim = ReferenceTrim(False, lambda kind, message: events.append((kind, message)))
    x, ref = _frames(300, offset_um=4.0, scale_ppm=-300.0)
    fixes, flags = _Live(trim).feed(x, ref)
    assert [kind for kind, _ in events] == ["scale_drift"]
    assert flags[-1] == "scale"  # what the validity monitor is told
    assert [f.x_mm for f in fixes] == list(x)
    status = trim.status()
    assert status["enabled"] is False and status["active"] is False and status["drift"] is True
    assert abs(status["window"]["offset_um"] - 4.0) < 5 * status["window"]["offset_sigma_um"]


def test_the_daemons_watch_flags_an_episode_of_frames_off_the_grating_as_batch_tracking_does():
    """40 frames placed 4 bounds off while χ² stays quiet (a smudge coming into view): the daemon's
    watch, which reads the trim's monitor, keeps the running mean of camera − grating as batch
    tracking's scale watch does, and flags the episode long before the line (fed the same frames) would."""
    live = _Live(ReferenceTrim(False))
    rng = np.random.default_rng(4)
    n, start, stop = 300, 200, 240
    ref = np.linspace(0.0, 10.0, n)
    err_um = rng.normal(0.0, BOUND_MM * 1e3, n)
    err_um[start:stop] -= 4.0 * BOUND_MM * 1e3
    x = ref + err_um * 1e-3
    _, flags = live.feed(x, ref)
    assert not any(flags[:start])
    assert set(flags[start + 15:stop]) == {"scale"}


def test_the_trim_needs_evidence_corrects_the_stream_and_is_cleared_by_reset_and_by_a_new_model():
    events: list[tuple[str, str]] = []
    trim = ReferenceTrim(True, lambda kind, message: events.append((kind, message)))
    live = _Live(trim)
    steady_x, steady_ref = _frames(600, 0.0, 0.0, seed=1)
    assert all(f.x_mm == xi for f, xi in zip(_feed(live, steady_x, steady_ref), steady_x)) and not events
    x, ref = _frames(1500, offset_um=4.0, scale_ppm=-300.0, seed=2)
    fixes = _feed(live, x, ref)
    kinds = [kind for kind, _ in events]
    assert kinds[:2] == ["scale_drift", "trim_applied"] and set(kinds) == {"scale_drift", "trim_applied"}
    assert len(kinds) < 20  # refined in a few steps, not every frame
    late = np.array([f.x_mm for f in fixes[-500:]]) - ref[-500:]
    assert abs(np.mean(late)) * 1e3 < 0.3 and np.std(late) * 1e3 < 1.1 * BOUND_MM * 1e3
    status = trim.status()
    assert status["active"] and abs(status["scale_ppm"] + 300.0) < 5 * status["scale_sigma_ppm"]
    assert abs(status["offset_um"] - 4.0) < 5 * status["offset_sigma_um"] and status["frames"] >= 30
    message = fix_message(1, SimpleNamespace(t=0.0, reference_mm=ref[-1], frame=SimpleNamespace(frame_id=1)),
                          fixes[-1], 0)
    trim.annotate(message, fixes[-1])
    assert math.isfinite(message["trim_um"]) and message["trim_sigma_um"] > 0
    assert trim.reset() and events[-1][0] == "trim_cleared" and not trim.status()["active"]
    assert not trim.reset()  # nothing left to clear
    _feed(live, x[:100], ref[:100])
    assert trim.status()["active"]  # the drift is still there: fresh evidence re-applies it
    live.install()  # a calibration
    assert events[-1] == ("trim_cleared", "trim cleared (a new model is installed)")


def test_a_daemon_on_a_growing_print_flags_it_trims_it_shows_it_and_resets_it(tmp_path) -> None:
    # the print keeps growing, 10 ppm per simulated second (100 per wall second at the fast clock),
    # about its end: calibration catches one moment of it, tracking sees the camera leave the grating
    growing = {"camera": {"effects": "target_growth:ppm=20000:at=0:ramp_s=2000"}}
    app = create_app(fast_settings(tmp_path, growing, trim=True))
    with TestClient(app) as client:
        wait_state(client, "tracking", 60.0)  # generous: a loaded machine's sweep; the wait ends when it is there
        assert client.get("/api/status").json()["trim"]["enabled"] is True
        trim = wait_for(lambda: (doc := client.get("/api/status").json()["trim"]) and doc["active"] and doc,
                        60.0, "a trim applied")
        # the stage rests: the line is known where it stands, and there it is beyond 5 of its σ (from a
        # window of at least the monitor's minimum: how many frames it took depends on how far the
        # print had grown by the time tracking began, 16 to 30+ here)
        assert trim["frames"] >= MIN_FRAMES and abs(trim["at_mean_um"]) > 5 * trim["at_mean_sigma_um"]
        kinds = [event["kind"] for event in client.get("/api/events").json()]
        assert kinds.index("scale_drift") < kinds.index("trim_applied")
        assert client.post("/api/trim/reset").status_code == 401
        token = {"Authorization": f"Bearer {client.app.state.storage.token_path.read_text().strip()}"}
        answer = client.post("/api/trim/reset", headers=token).json()
        assert answer["cleared"] is True and answer["trim"]["active"] is False
        assert "trim_cleared" in [event["kind"] for event in client.get("/api/events").json()]
