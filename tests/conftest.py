"""Shared fixtures: the seed paper's rig rendered from Table 2 (NOTES.md), seeded; and the
``unit`` / ``system`` marks.

A *system* test runs real parts together on the wall clock: a daemon process or its app with live
threads, a browser, a pseudo-terminal or a GigE Vision camera on loopback (tests/service,
tests/web, and the driver tests that open devices). Everything else is a *unit* test: numerics
and files only, seeded, fast. ``pytest -m unit`` is the quick check while editing the core.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.recording import Recording
from graytrack.drivers.sim import paper
from graytrack.drivers.sim.scenarios import build_rig

SYSTEM_FOLDERS = ("service", "web", "drivers", "client")
# BLAS threads per test worker: the cores shared out among the workers (pytest -n), at least one. OpenBLAS's
# threads spin between calls; two workers on two cores, each with two threads, ran a closed-loop test twice side
# by side in 50-76 s against 40 s with one thread each (service/blas.py: the daemon runs one for the same reason).
BLAS_ENV = "OPENBLAS_NUM_THREADS"


def _workers(config: pytest.Config) -> int:
    """The test workers this run starts (0: none, the tests run in this process); none in a worker itself."""
    if hasattr(config, "workerinput"):
        return 0
    workers = getattr(config.option, "numprocesses", None)
    return workers if isinstance(workers, int) else 0


def _share_httpx_tls_context() -> None:
    """httpx's top-level calls (``httpx.get(...)``, as the tests poll a daemon) build a client each, and each client
    a TLS context that loads certifi's CA bundle: ~60 ms of CPU a call, for requests to http://127.0.0.1 that never
    use it; polled every 20 ms, a waiting test spent most of a core on it. In the test processes the default context
    (verify=True, no client certificate, the same environment) is built once and handed to every client that asks
    for it; every other request builds its own as before. What is verified, and how, is unchanged."""
    try:
        from httpx._transports import default
    except ImportError:  # another httpx: every client builds its own, as before
        return
    build = default.create_ssl_context
    if getattr(build, "shared", False):
        return
    contexts: dict[tuple[object, ...], object] = {}

    def create_ssl_context(verify: object = True, cert: object = None, trust_env: bool = True) -> object:
        if verify is not True or cert is not None:
            return build(verify=verify, cert=cert, trust_env=trust_env)
        key = (trust_env, os.environ.get("SSL_CERT_FILE"), os.environ.get("SSL_CERT_DIR"))
        if key not in contexts:
            contexts[key] = build(verify=verify, cert=cert, trust_env=trust_env)
        return contexts[key]

    create_ssl_context.shared = True  # type: ignore[attr-defined]
    default.create_ssl_context = create_ssl_context


_share_httpx_tls_context()


def pytest_configure(config: pytest.Config) -> None:
    config.pluginmanager.register(HeavyFirst(), "graytrack-heavy-first")
    # set before the workers start, which inherit it (and so do the daemons and commands tests start from them);
    # a value the caller set is kept
    if (workers := _workers(config)) > 0:
        os.environ.setdefault(BLAS_ENV, str(max(1, (os.cpu_count() or 1) // workers)))


def pytest_sessionstart(session: pytest.Session) -> None:
    """Before the workers start (xdist starts them last): tracking's compiled kernels loaded once here, which on a
    fresh clone compiles them into numba's disk cache (~30 s of CPU) for every worker and daemon to load from
    (under a second), rather than each worker compiling them at once on its first tracking test."""
    if _workers(session.config) > 0:
        from graytrack.service.heap import warm_tracking

        warm_tracking(("watches", "estimator"))


# The files holding tests marked ``alone``, as collected (before ``-m`` deselects them): tests/test_alone_files.py
# checks them against the files make test's alone run reads.
ALONE_FILES = pytest.StashKey[set[Path]]()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    config.stash[ALONE_FILES] = {item.path for item in items if item.get_closest_marker("alone") is not None}
    for item in items:
        parts = item.path.relative_to(config.rootpath).parts
        system = len(parts) > 2 and parts[0] == "tests" and parts[1] in SYSTEM_FOLDERS
        if item.get_closest_marker("unit") is not None:
            continue
        item.add_marker(pytest.mark.system if system else pytest.mark.unit)


# The suite's heaviest parts, in seconds of a test worker (summed `--durations`, rounded; the mean of two runs of the
# twenty-sixth session's tree), whole for the folders
# whose package-scoped fixtures (a daemon, a Dask cluster) would be made again if their modules were split.
# What is not named weighs nothing here: it fills in after them.
HEAVY_S = {
    "tests/client": 69, "tests/diagnosis/test_closed_loop.py": 57, "tests/web/test_status_page.py": 53,
    "tests/batch": 31, "tests/core/test_validity.py": 29, "tests/service/test_lifecycle.py": 28,
    "tests/service/test_history.py": 25, "tests/core/test_geometry_check.py": 23, "tests/core/test_estimator.py": 22,
    "tests/service/test_sensor_map_store.py": 18, "tests/service/test_limits.py": 18,
    "tests/diagnosis/test_bad_pixels.py": 18, "tests/service/test_print_map_store.py": 17,
    "tests/service/test_schemathesis.py": 16, "tests/service/test_disk_full.py": 15,
    "tests/diagnosis/test_robust_end_to_end.py": 15, "tests/diagnosis/test_period_refit.py": 15,
    "tests/service/test_texture_store.py": 14, "tests/service/test_supervision.py": 14,
    "tests/diagnosis/test_target_growth_end_to_end.py": 12, "tests/core/test_transients.py": 12,
    "tests/service/test_move_calibration_race.py": 11, "tests/service/test_epics.py": 11,
    "tests/core/test_sensor_map.py": 10,
}
WHOLE_FOLDERS = ("tests/client", "tests/batch")


def _group(item: pytest.Item, root: Path) -> str:
    path = item.path.relative_to(root).as_posix()
    return next((folder for folder in WHOLE_FOLDERS if path.startswith(folder + "/")), path)


def _chunks(n_items: int, n_workers: int) -> list[int]:
    """How many of the collected tests pytest-xdist's worksteal hands each worker at the start: the first
    ``n // workers`` in order, then ``remaining // workers left`` of the rest, and so on (each works its share in
    order, then takes the far end of the longest share still waiting)."""
    sizes, left = [], n_items
    for remaining in range(n_workers, 0, -1):
        sizes.append(left // remaining)
        left -= sizes[-1]
    return sizes


class HeavyFirst:
    """A plugin of its own (registered in :func:`pytest_configure`): this conftest's own collection hook marks the
    tests before ``-m`` deselects, this one orders what is left after."""

    @pytest.hookimpl(trylast=True)
    def pytest_collection_modifyitems(self, config: pytest.Config, items: list[pytest.Item]) -> None:
        heavy_first(config, items)


def heavy_first(config: pytest.Config, items: list[pytest.Item]) -> None:
    """On a worksteal worker, the order that starts every worker on heavy parts: each heavy part (HEAVY_S) goes to
    the share that weighs least so far, heaviest first, and the light tests fill each share up to its size after
    them. Left in file order, a share could end on a test of a minute (the page tests come last) that no other
    worker can take from it while it runs; light tests at each share's end are what the worker that finishes first
    takes over. Every worker computes the same order (xdist checks that they collected the same)."""
    workers = int(getattr(config, "workerinput", {}).get("workercount", 0))
    if workers < 2 or config.getoption("dist", None) != "worksteal" or not items:
        return
    groups: dict[str, list[pytest.Item]] = {}
    for item in items:
        groups.setdefault(_group(item, config.rootpath), []).append(item)
    heavy = sorted((key for key in groups if key in HEAVY_S), key=lambda key: -HEAVY_S[key])
    shares: list[list[pytest.Item]] = [[] for _ in range(workers)]
    weights = [0] * workers
    for key in heavy:
        lightest = weights.index(min(weights))
        shares[lightest] += groups[key]
        weights[lightest] += HEAVY_S[key]
    light = [item for key, group in groups.items() if key not in HEAVY_S for item in group]
    for share, size in zip(shares, _chunks(len(items), workers)):
        take = max(0, size - len(share))
        share += light[:take]
        del light[:take]
    shares[-1] += light
    items[:] = [item for share in shares for item in share]


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    with path.open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def shared_once(factory: pytest.TempPathFactory, name: str, build: Callable[[Path], None]) -> Path:
    """A folder ``build(folder)`` filled once for the whole run, whichever test worker asks first: the others wait
    for it and read the same folder (its readers must copy what they change). Keyed by ``name`` under the run's
    shared temporary folder (each xdist worker's base temp is a child of it); a build that failed is tried again
    by the next one to ask, from an empty folder."""
    base = factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder, done = root / f"shared-{name}", root / f"shared-{name}.done"
    with _locked(root / f"shared-{name}.lock"):
        if not done.exists():
            if folder.exists():
                import shutil

                shutil.rmtree(folder)
            folder.mkdir()
            build(folder)
            done.touch()
    return folder


@pytest.fixture(scope="session")
def _one_calibration(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The data directory a daemon on the fast test rig (tests/service/helpers.py FAST_TABLES) leaves when it has
    calibrated itself at its first start and stopped: one calibration, done and active, and its record. Made once
    for the run (:func:`shared_once`: the test workers share it) and read only: :func:`calibrated` copies it."""

    def make(folder: Path) -> None:
        from fastapi.testclient import TestClient

        from graytrack.service.daemon.app import create_app
        from tests.service.helpers import fast_settings, wait_state

        with TestClient(create_app(fast_settings(folder / "data"))) as client:
            wait_state(client, "tracking", 60.0)

    return shared_once(tmp_path_factory, "one-calibration", make) / "data"


@pytest.fixture(scope="session")
def calibrated(_one_calibration: Path) -> Callable[[Path], Path]:
    """``calibrated(data)``: ``data`` made a copy of :func:`_one_calibration`'s data directory, for a daemon that
    starts tracking on the rig's model of record at once, where the test is about what happens after the daemon's
    first calibration, not about that calibration (a sweep and a fit on the wall clock, seconds of a busy test
    worker). Both engines' tracking kernels are loaded in this process first: a daemon's rig clock starts with its
    app, and the daemon made next then opens its rig without spending that clock on loading them."""
    from graytrack.service.heap import warm_tracking

    warm_tracking(("watches", "estimator"))

    def copy(data: Path) -> Path:
        import shutil

        shutil.copytree(_one_calibration, data, dirs_exist_ok=True)  # ``data`` may be a test's own empty tmp_path
        return data

    return copy


PAPER_META = {"pixel_pitch_mm": paper.PIXEL_PITCH_MM, "period_mm": 8.6, "source": "tests: Table 2 field"}


def paper_recording(n_frames: int = 1000, n_rows: int = 1, seed: int = 1, shift_mm: float = 0.0,
                    meta: dict | None = None) -> Recording:
    """A sweep over the paper's 10.46 mm stroke with σ = 0.7 gray per pixel."""
    x_mm = np.linspace(0.0, paper.STROKE_MM, n_frames) + shift_mm
    frames = paper.paper_frames(x_mm, n_rows=n_rows, rng=np.random.default_rng(seed))
    frames = frames[:, 0, :] if n_rows == 1 else frames
    return Recording(frames.astype(np.float32), np.arange(n_frames) * 1e-3, x_mm,
                     dict(PAPER_META if meta is None else meta))


@pytest.fixture(scope="session")
def paper_cal() -> Recording:
    return paper_recording(seed=1)


@pytest.fixture(scope="session")
def paper_val() -> Recording:
    """Held-out frames: other noise, positions between the calibration's."""
    return paper_recording(seed=2, shift_mm=0.0047)


@pytest.fixture(scope="session")
def paper_models(paper_cal):
    return {kind: calibrate(paper_cal, kind) for kind in ("ideal", "paper")}


@functools.lru_cache(maxsize=None)
def warm_kernels() -> None:
    """Every compiled kernel the suite runs, compiled into numba's disk cache (``make test`` runs this while lint
    does): the tracker's (the daemon's own warm-up, service/heap.py) and those of calibration and batch tracking,
    which on a fresh clone each test worker and each daemon it starts would otherwise compile on first use, ~10 s
    of CPU apiece (loaded from the cache in well under a second after)."""
    from graytrack.core.tracking import track
    from graytrack.service.heap import warm_tracking

    warm_tracking(("watches", "estimator"))
    recording = paper_recording(200)
    model = calibrate(recording, "paper").model
    track(model, recording.frames, reference=recording.reference, light="auto", robust=True)


@functools.lru_cache(maxsize=None)
def rig_model(scenario: str, effects: str = "", seed: int = 3, seconds: float = 20.0):
    """The seed paper's model calibrated on ``seconds`` of the virtual rig (``build_rig(scenario, effects,
    seed)``): made once a test process for every module that tracks its later runs with it (seeded: the same
    model every time; tracking reads a model and never changes it, so the modules share one)."""
    calibration, _ = build_rig(scenario, effects, seed=seed).record(seconds)
    return calibrate(calibration, "paper").model


def estimator_figures(model, run, truth, grating: str = "check", settings=None) -> dict[str, float]:
    """``run`` tracked by the estimator (core/estimator/, its ``settings`` where given) against ``truth``, frame by
    frame: the error's std (µm), its rms over the stated bound (``pull``), the share of frames flagged and the frames
    4+ bounds off unflagged (``silent``); from the image alone (``grating`` "none") the error is taken up to whole
    periods."""
    from graytrack.core.estimator import filter as estimator

    estimates = estimator.track(model, run.frames, run.t, run.reference, grating=grating, settings=settings)
    error_um = (np.array([e.x_mm for e in estimates]) - truth.x_mm) * 1e3
    if grating == "none":  # placed from the image alone: its origin is known up to whole periods
        period_um = model.period_mm * 1e3
        error_um -= period_um * np.round(np.median(error_um) / period_um)
    bound_um = np.array([e.crlb_mm for e in estimates]) * 1e3
    stale = np.array([e.stale for e in estimates])
    far = np.abs(error_um) > 4.0 * bound_um
    return {"std": float(np.std(error_um)), "pull": float(np.sqrt(np.mean((error_um / bound_um) ** 2))),
            "flagged": float(stale.mean()), "silent": int((far & ~stale).sum())}


def calibrated_rig(scenario: str, effects: str = "", seed: int = 3, calibration_s: float = 20.0,
                   run_s: float = 10.0):
    """(the seed paper's model, its calibration recording, a later run, its truth) of the virtual rig
    ``build_rig(scenario, effects, seed)``: calibrated on one run and measured on another."""
    calibration, _ = build_rig(scenario, effects, seed=seed).record(calibration_s)
    run, truth = build_rig(scenario, effects, seed=seed, run=1).record(run_s)
    return calibrate(calibration, "paper").model, calibration, run, truth
