"""The watches' compiled loops (core/watches/_kernels.py) against their Python ``step``, frame by
frame: the same flags and the same state, bit for bit."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from graytrack.core.reference_monitor import Line, ReferenceMonitor, StructureProfile, follow
from graytrack.core.watches import _kernels

pytestmark = pytest.mark.skipif(not _kernels.COMPILED, reason="numba missing: the watches step in Python")


def drifting_run(n: int, seed: int, resolution_mm: float = 0.0):
    """Positions against a grating: noise, a scale drift from mid-run, outliers, a jump, gaps."""
    rng = np.random.default_rng(seed)
    reference = 5.0 + 4.0 * np.sin(np.linspace(0.0, 6.0, n))
    if resolution_mm:
        reference = np.round(reference / resolution_mm) * resolution_mm
    bound = 1e-4 * (1.0 + rng.random(n))
    drift = np.where(np.arange(n) > n // 2, 400e-6 * (reference - 5.0), 0.0)
    x = reference + rng.normal(size=n) * bound + drift
    x[rng.random(n) < 0.01] += 0.05  # outliers
    x[int(0.7 * n):int(0.7 * n) + 40] += 0.003  # a jump for a while: the window restarts
    reference[rng.random(n) < 0.02] = np.nan
    bound[rng.random(n) < 0.01] = 0.0
    feed = rng.random(n) < 0.95
    return x, reference, bound, feed


MONITORS = {
    "plain": lambda: ReferenceMonitor(5.0, 4.0),
    "small window": lambda: ReferenceMonitor(5.0, 4.0, window=60, min_frames=30, floor_um=0.05),
    "calibrated": lambda: ReferenceMonitor(5.0, 4.0, reference_sigma_mm=1e-3 / 12 ** 0.5, resolution_mm=1e-3,
                                           calibration_frames=300, calibration_x_std_mm=2.0,
                                           calibration_structure_um=0.1,
                                           calibration=Line(0.1, 20.0, (0.01, 0.001, 100.0), 5.0, 300, 5.2)),
    "trimmed": lambda: ReferenceMonitor(5.0, 4.0, calibration_frames=2,
                                        baseline=Line(-0.2, -50.0, (0.02, 0.0, 50.0), 5.0)),
}


def state(monitor: ReferenceMonitor) -> dict:
    return copy.deepcopy({f.name: getattr(monitor, f.name) for f in dataclasses.fields(monitor)})


@pytest.mark.parametrize("name", MONITORS)
@pytest.mark.parametrize("n", [5, 3000, 9000])
def test_reference_monitor_many_frames_at_once_as_frame_by_frame(monkeypatch, name, n):
    x, reference, bound, feed = drifting_run(n, n, resolution_mm=1e-3 if name == "calibrated" else 0.0)
    compiled, stepped = MONITORS[name](), MONITORS[name]()
    rises_compiled, rises_stepped = [], []
    flags = compiled.observe_many(x, reference, bound, feed,
                                  on_rise=lambda k: rises_compiled.append((k, state(compiled))))
    monkeypatch.setattr(_kernels, "COMPILED", False)
    expected = stepped.observe_many(x, reference, bound, feed,
                                    on_rise=lambda k: rises_stepped.append((k, state(stepped))))
    assert np.array_equal(flags, expected)
    assert state(compiled) == state(stepped)
    assert [k for k, _ in rises_compiled] == [k for k, _ in rises_stepped]
    assert all(a == b for (_, a), (_, b) in zip(rises_compiled, rises_stepped))
    if n == 9000 and name in ("plain", "small window"):
        assert flags.any()  # the drift was seen: the comparison covered flagged frames


def test_follow_without_trim_as_frame_by_frame(monkeypatch):
    x, reference, bound, feed = drifting_run(4000, 7)
    fast = follow(ReferenceMonitor(5.0, 4.0), x, reference, bound, feed)
    monkeypatch.setattr(_kernels, "COMPILED", False)
    slow = follow(ReferenceMonitor(5.0, 4.0), x, reference, bound, feed)
    assert fast.events and fast.events == slow.events
    assert fast.final == slow.final
    for name in ("stale", "x_mm", "trim_um", "trim_sigma_um"):
        assert np.array_equal(getattr(fast, name), getattr(slow, name))


def sign_columns(n: int, seed: int) -> dict[str, list]:
    """Frames' signs that make every watch speak somewhere: a dimmed light solved, transients that
    wander then stay put, information lost, the camera scattering off the grating, gaps, suspect χ²."""
    from graytrack.core.validity import SIGN_FIELDS

    rng = np.random.default_rng(seed)
    k = np.arange(n)
    stretch = lambda a, b: (k >= a * n) & (k < b * n)  # noqa: E731
    x = 2.0 + 6.0 * (k / n) + rng.normal(size=n) * 1e-4
    reference = x + rng.normal(size=n) * np.where(stretch(0.6, 0.8), 2e-3, 1e-4)
    reference[rng.random(n) < 0.03] = np.nan
    reference[rng.random(n) < 0.005] += 0.5  # single readings gone wrong: clipped at the gates
    reference[int(0.55 * n):int(0.55 * n) + 25] += 0.01  # a run of them: a jump
    x = x + np.where(k > 0.8 * n, 1e-3 * (x - 5.0) + 2e-3, 0.0)  # a scale drift at the end
    information = 1e8 * (1.0 + 0.1 * rng.random(n)) * np.where(stretch(0.3, 0.5), 0.3, 1.0)
    information[rng.random(n) < 0.01] = np.nan
    transient = np.where(stretch(0.1, 0.3) & (rng.random(n) < 0.8), rng.integers(1, 9, n), 0)
    at = np.where(stretch(0.1, 0.2), rng.uniform(0, 100, n), 40.0 + rng.normal(size=n))
    columns = {
        "frame": k.tolist(), "chi2": (1.0 + rng.random(n)).tolist(), "information": information.tolist(),
        "information_calibrated": [float("nan")] * n,
        "gain": np.where(stretch(0.4, 0.7), 0.4, 1.0 + 0.01 * rng.normal(size=n)).tolist(),
        "offset_gray": [0.0] * n, "focus": np.where(rng.random(n) < 0.1, 0.3, 0.0).tolist(),
        "focus_sigma": [float("nan")] * n, "rejected_px": np.where(stretch(0.35, 0.45), 2, 0).tolist(),
        "transient_px": transient.tolist(), "transient_at": np.where(transient > 0, at, np.nan).tolist(),
        "x_mm": x.tolist(), "reference_mm": reference.tolist(), "placed": (rng.random(n) > 0.02).tolist(),
        "rows_averaged": [1] * n, "free_light": (stretch(0.35, 0.75) | (rng.random(n) < 0.05)).tolist(),
        "field": (rng.random(n) < 0.02).tolist(), "chi2_average": [1.0] * n,
        "chi2_suspect": (stretch(0.45, 0.47) | stretch(0.62, 0.66)).tolist(), "chi2_stale": [False] * n,
        "explain": [None] * n,
        "stretch": [None] * n, "moving": stretch(0.5, 0.55).tolist(),
        "period_guess": stretch(0.05, 0.1).tolist(), "pulled": stretch(0.56, 0.58).tolist()}
    assert set(columns) == set(SIGN_FIELDS)
    return columns


def watches():
    from graytrack.core.watches.bound import BoundWatch
    from graytrack.core.watches.chi2 import ChiSquareWatch
    from graytrack.core.watches.far_off import FarOffWatch
    from graytrack.core.watches.focus import FocusWatch
    from graytrack.core.watches.grating import GratingWatch
    from graytrack.core.watches.light import LightWatch
    from graytrack.core.watches.scale import ScaleWatch
    from graytrack.core.watches.transients import TransientWatch

    table = 1e8 * (1.0 + 0.5 * np.sin(np.linspace(0.0, 20.0, 700)) ** 2)
    return {"bound": lambda: BoundWatch(1.0, 10.0 / 699, table), "chi2": ChiSquareWatch, "focus": FocusWatch,
            "far_off": lambda: FarOffWatch(4e8, 1.2),
            "grating": lambda: GratingWatch(1.3, 1.9), "light": LightWatch, "transients": TransientWatch,
            "scale": lambda: ScaleWatch(ReferenceMonitor(5.0, 4.0, window=100, floor_um=0.01)),
            "scale far off": lambda: ScaleWatch(ReferenceMonitor(5.0, 4.0, window=100, floor_um=0.01),
                                                far_off=FarOffWatch(4e8, 1.2))}


def both_ways(at_once, stepped, columns: dict[str, list]) -> tuple[list, list]:
    """(families of ``at_once`` taking the frames chunk by chunk as batch tracking hands them, a chunk
    of one frame among them; those of ``stepped`` frame by frame)."""
    from graytrack.core.validity import Columns, _observe_all

    n = len(columns["frame"])
    families = []
    for start, stop in ((0, 1000), (1000, 1001), (1001, n)):
        part = Columns({key: values[start:stop] for key, values in columns.items()})
        families += _observe_all(at_once, part, stop - start)
    return families, [stepped.step(*row) for row in zip(*(columns[field] for field in stepped.reads))]


@pytest.mark.parametrize("name", sorted(watches()))
def test_each_watch_many_frames_at_once_as_frame_by_frame(name):
    """``step_many`` (chunk by chunk, as batch tracking calls it) gives ``step``'s families and state."""
    n = 3000
    columns = sign_columns(n, 11)
    make = watches()[name]
    at_once, stepped = make(), make()
    families, expected = both_ways(at_once, stepped, columns)
    assert families == expected
    assert any(families) or name in ("chi2", "focus")
    inner = lambda w: w.monitor if name.startswith("scale") else w  # noqa: E731
    if name == "scale far off":  # the far-off judgement it carries, named decisively (core/validity.py Decisive)
        assert any(type(f).__name__ == "Decisive" for f in families)
        assert all(type(a) is type(b) for a, b in zip(families, expected))
        assert vars(at_once.far_off) == vars(stepped.far_off)
    assert vars(inner(at_once)).keys() == vars(inner(stepped)).keys()
    for key, value in vars(inner(at_once)).items():
        if key in ("_array",):
            continue
        other = vars(inner(stepped))[key]
        assert value == other or (value != value and other != other), key


def test_batch_tracking_gives_the_same_flags_compiled_or_stepped(monkeypatch, paper_models, paper_val):
    """The whole validity monitor in batch ``track``: a dimmed light with a stuck pixel, then a scale
    drift against the grating (flags for ``scale`` and more), the same compiled as frame by frame."""
    from graytrack.core.tracking import track

    model = paper_models["paper"].model
    frames = paper_val.frames * np.float32(0.8) + np.float32(10.0)
    frames[..., 37] = 255.0
    reference = paper_val.reference * (1.0 + 4e-4 * (np.arange(paper_val.n_frames) > 300))
    fast = track(model, frames, reference=reference, light="auto", robust=True)
    monkeypatch.setattr(_kernels, "COMPILED", False)
    slow = track(model, frames, reference=reference, light="auto", robust=True)
    assert fast.stale.any() and set(fast.stale_reason[fast.stale]) >= {"scale"}
    for name in ("x_mm", "crlb_mm", "locked", "chi2", "stale", "stale_reason", "rejected_px", "gain"):
        assert np.array_equal(getattr(fast, name), getattr(slow, name), equal_nan=getattr(fast, name).dtype.kind == "f")


def test_repeated_frames_keep_the_verdict_before_them_chunk_by_chunk():
    """tracking._judge (vectorised) as the frame-by-frame rule: a shown frame takes the monitor's
    reason, a repeated one the verdict of the frame before it (across chunks too)."""
    from graytrack.core import tracking

    def frame_by_frame(reasons, repeated, stale, stale_reason, start, stop):
        reason = (str(stale_reason[start - 1]) or None) if start else None
        reasons = iter(reasons)
        for k in range(start, stop):
            if not repeated[k]:
                reason = next(reasons)
            stale[k], stale_reason[k] = reason is not None, reason or ""

    class Pending:
        def __init__(self, reasons):
            self.reasons = reasons

        def verdicts(self):
            return self.reasons

    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(1, 40))
        repeated = rng.random(n) < rng.choice([0.0, 0.3, 0.9, 1.0])
        edges = sorted({0, n, *rng.integers(0, n, 3).tolist()})
        expected = np.zeros(n, bool), np.full(n, "", "<U10")
        got = np.zeros(n, bool), np.full(n, "", "<U10")
        for start, stop in zip(edges[:-1], edges[1:]):
            reasons = [rng.choice([None, "light", "scale"]) for _ in range(int((~repeated[start:stop]).sum()))]
            frame_by_frame(reasons, repeated, *expected, start, stop)
            tracking._judge(Pending(reasons), repeated, *got, start, stop)
        assert np.array_equal(expected[0], got[0]) and np.array_equal(expected[1], got[1])


@pytest.mark.parametrize("share", [0.0, 0.01, 0.03, 0.5])
def test_the_focus_watch_many_frames_at_once_as_frame_by_frame(share):
    """Estimates on a few frames (the window never fills: taken at once, gaps and clearings as
    frame by frame) or on many (judged frame by frame): the families and the window as ``step``'s."""
    from graytrack.core.validity import Columns, _observe_all
    from graytrack.core.watches.focus import FocusWatch

    n = 3000
    columns = sign_columns(n, 5)
    rng = np.random.default_rng(5)
    estimated = rng.random(n) < share
    columns["focus_sigma"] = np.where(estimated, 0.05 + 0.01 * rng.random(n), np.nan).tolist()
    columns["focus"] = np.where(estimated, 0.6 + 0.05 * rng.normal(size=n), 0.0).tolist()
    at_once, stepped = FocusWatch(), FocusWatch()
    families = []
    for start, stop in ((0, 700), (700, 701), (701, 2000), (2000, n)):
        part = Columns({key: values[start:stop] for key, values in columns.items()})
        families += _observe_all(at_once, part, stop - start)
    expected = [stepped.step(*row) for row in zip(*(columns[field] for field in stepped.reads))]
    assert families == expected
    assert list(at_once._estimates) == list(stepped._estimates) and at_once._missing == stepped._missing
    if share == 0.5:
        assert "focus" in families


@pytest.mark.parametrize("log", [False, True])
def test_scale_watch_many_frames_at_once_reads_the_scatter_frame_by_frame(log):
    """The scale watch's running mean gates each frame with the monitor's scatter as it stood before
    that frame (its line refitted every few frames in between): chunk by chunk as frame by frame,
    families, the mean's state and the per-frame log (``track``'s CLI asks for it) bit for bit."""
    from graytrack.core.validity import Columns, _observe_all
    from graytrack.core.watches.scale import ScaleWatch

    n = 3000
    columns = sign_columns(n, 11)
    columns["chi2_suspect"] = [False] * n  # a suspect frame is stepped on its own: here every chunk goes at once
    make = lambda: ScaleWatch(ReferenceMonitor(5.0, 4.0, window=100, floor_um=0.01), log=log)  # noqa: E731
    at_once, stepped = make(), make()
    families, scatters = [], set()
    for start, stop in ((0, 1000), (1000, 1001), (1001, n)):
        part = Columns({key: values[start:stop] for key, values in columns.items()})
        families += _observe_all(at_once, part, stop - start)
    expected = []
    for row in zip(*(columns[field] for field in stepped.reads)):
        scatters.add(stepped.monitor.scatter)
        expected.append(stepped.step(*row))
    assert len(scatters) > 100  # the scatter moved within every chunk: what the mean's gate reads
    assert families == expected and any(families)
    assert vars(at_once._off) == vars(stepped._off)
    assert at_once.log == stepped.log and (len(at_once.log) == n if log else at_once.log is None)


SCALE_MONITORS = {
    "plain": lambda: ReferenceMonitor(5.0, 4.0, window=100, floor_um=0.01),
    # a calibration's line and the model's own error along the stroke, taken out of camera − grating
    "calibrated": lambda: ReferenceMonitor(
        5.0, 4.0, window=100, floor_um=0.01, reference_sigma_mm=1e-3 / 12 ** 0.5, resolution_mm=1e-3,
        calibration_frames=300, calibration_x_std_mm=2.0, calibration_structure_um=0.1, place_sigma_um=0.05,
        calibration=Line(0.1, 20.0, (0.01, 0.001, 100.0), 5.0, 300, 5.2),
        structure=StructureProfile((2.5, 4.0, 6.5), (0.3, -0.2, 0.1), 0.05, 0.02)),
}


@pytest.mark.parametrize("monitor", SCALE_MONITORS)
def test_scale_watch_names_the_stretch_frame_by_frame_in_a_drifted_chunk(monitor):
    """A chunk whose line drifts, with suspect frames: the monitor and the running mean take it at once
    (the line recorded after each frame, the mean compiled), the carried magnification watch and the
    naming of the stretch (a lens's, a print's) go frame by frame. Against :meth:`ScaleWatch.step` frame
    by frame: families, the per-frame log, the running mean's, the monitor's and the magnification
    watch's state bit for bit."""
    from graytrack.core.watches.magnification import MagnificationWatch
    from graytrack.core.watches.scale import ScaleWatch

    n = 3000
    columns = sign_columns(n, 12)
    rng = np.random.default_rng(5)
    k = np.arange(n)
    m = np.where(k > 0.75 * n, 1500e-6, 0.0) + 300e-6 * rng.normal(size=n)  # a lens's stretch near the drift
    columns["stretch"] = [None if rng.random() < 0.02 else (lambda m=m[i]: (m, 300e-6)) for i in range(n)]
    make = lambda: ScaleWatch(SCALE_MONITORS[monitor](), log=True, magnification=MagnificationWatch(8.6),  # noqa: E731
                              local=SCALE_MONITORS[monitor]())
    at_once, stepped = make(), make()
    families, expected = both_ways(at_once, stepped, columns)
    assert at_once.local.frames == stepped.local.frames > 0 and at_once.local.estimate == stepped.local.estimate
    assert families == expected
    assert {"scale", "magnification"} <= set(families) and ("geometry" in families or monitor != "plain")
    assert at_once.log == stepped.log and len(at_once.log) == n
    assert vars(at_once._off) == vars(stepped._off)
    for a, b in zip(at_once.monitor.snapshot(), stepped.monitor.snapshot()):
        assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b
    for name in ("_normal", "_noise", "_right", "_scalars"):
        assert np.array_equal(getattr(at_once.magnification, name), getattr(stepped.magnification, name)), name


def test_the_calibrated_information_is_made_once_a_model_and_a_changed_model_makes_its_own(paper_models):
    """Every tracker of a model has a bound and a far-off watch, both from the model's calibrated information:
    made once a model, read-only, the same figures as made afresh; a copy with another period makes its own."""
    from graytrack.core.watches.bound import _calibrated_information, calibrated_information

    model = paper_models["paper"].model
    first = calibrated_information(model)
    assert calibrated_information(model) is first and not first[2].flags.writeable
    fresh = _calibrated_information(model)
    assert first[:2] == fresh[:2] and np.array_equal(first[2], fresh[2])
    moved = model.with_changes(period_mm=model.period_mm * 1.01, coeffs=model.coeffs)
    other = calibrated_information(moved)
    assert other is not first and other[1] != first[1]
    assert np.array_equal(other[2], _calibrated_information(moved)[2])
