"""The recording file contract: round trips, and a one-line refusal naming the key for bad files."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from graytrack.core.recording import STAGE_PHASES, Recording, RecordingError, acceleration_phases, load, save


def make(shape=(5, 8), dtype=np.uint16, meta=None) -> Recording:
    frames = (np.arange(np.prod(shape)) % 200).reshape(shape).astype(dtype)
    return Recording(frames, np.arange(shape[0]) * 0.01, np.linspace(0, 1, shape[0]), meta or {"period_mm": 8.6})


@pytest.mark.parametrize("shape", [(5, 8), (5, 3, 8)])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
def test_round_trip(tmp_path, shape, dtype):
    rec = make(shape, dtype, {"pixel_pitch_mm": 0.062, "period_mm": 8.62, "note": "x"})
    rec.reference[2] = np.nan
    back = load(save(rec, tmp_path / "r.npz"))
    assert back.frames.dtype == np.dtype(dtype) and back.frames.shape == shape
    np.testing.assert_array_equal(back.frames, rec.frames)
    np.testing.assert_array_equal(back.reference, rec.reference)
    assert back.meta == rec.meta and back.n_rows == (1 if len(shape) == 2 else 3)


def test_frames_are_deflated_only_where_it_pays(tmp_path):
    """A noisy float camera's frames barely deflate and are stored as they are (reading them back is a copy); an
    integer camera's are deflated; either way the file is numpy's own .npz and round-trips exactly."""
    rng = np.random.default_rng(4)
    light = 120.0 + 60.0 * np.sin(np.linspace(0.0, 40.0, 300 * 16 * 100)).reshape(300, 16, 100)
    noisy = (light + rng.normal(0.0, 1.5, light.shape)).astype(np.float32)
    counts = np.clip(np.round(light + rng.normal(0.0, 1.5, light.shape)), 0, 255).astype(np.uint8)
    t = np.arange(300) * 0.02
    for frames, stored in ((noisy, zipfile.ZIP_STORED), (counts, zipfile.ZIP_DEFLATED)):
        path = save(Recording(frames, t, np.linspace(0.0, 5.0, 300), {"period_mm": 8.62}), tmp_path / "r.npz")
        with zipfile.ZipFile(path) as archive:
            kinds = {info.filename: info.compress_type for info in archive.infolist()}
        assert kinds["frames.npy"] == stored
        assert kinds["t.npy"] == kinds["meta.npy"] == zipfile.ZIP_DEFLATED  # small: always deflated
        np.testing.assert_array_equal(load(path).frames, frames)
        with np.load(path) as data:  # numpy's own reader too
            np.testing.assert_array_equal(data["frames"], frames)
    assert (tmp_path / "r.npz").stat().st_size < 0.8 * counts.nbytes  # the integer camera's file did shrink


def test_the_stages_commanded_phases_round_trip_and_bad_ones_are_refused(tmp_path):
    rec = make(meta={"period_mm": 8.6, STAGE_PHASES: [[2.0, 2.05, 100.0], [0.1, 0.15, 50]]})
    back = load(save(rec, tmp_path / "r.npz"))
    np.testing.assert_array_equal(acceleration_phases(back.meta), [[0.1, 0.15, 50.0], [2.0, 2.05, 100.0]])
    assert acceleration_phases({}) is None
    for bad in ([[1.0, 0.5, 100.0]], [[0.0, 1.0, -5.0]], [[0.0, 1.0]], "fast", [[0.0, float("nan"), 1.0]],
                [[0.0, 1.0, True]]):
        with pytest.raises(RecordingError, match=STAGE_PHASES):
            save(make(meta={STAGE_PHASES: bad}), tmp_path / "bad.npz")


def write_raw(path, **arrays):
    np.savez(path, **arrays)
    return path


def good_arrays():
    return {"frames": np.zeros((4, 6), np.uint8) + 9, "t": np.arange(4.0), "reference": np.arange(4.0),
            "meta": np.array(json.dumps({"period_mm": 8.6}))}


@pytest.mark.parametrize(
    "change, message",
    [
        ({"frames": None}, "missing key 'frames'"),
        ({"t": np.arange(3.0)}, "t: expected shape"),
        ({"reference": np.arange(5.0)}, "reference: expected shape"),
        ({"frames": np.zeros((4, 6), np.int64)}, "frames: dtype int64"),
        ({"frames": np.zeros((4,), np.uint8)}, "frames: expected shape"),
        ({"frames": np.full((4, 6), np.nan, np.float32)}, "NaN"),
        ({"meta": np.array("{not json")}, "meta: not valid JSON"),
        ({"meta": np.array("[1, 2]")}, "meta: must be a JSON object"),
        ({"meta": np.array(json.dumps({"period_mm": -1}))}, "period_mm must be a positive number"),
        ({"t": np.array([0.0, np.nan, 2.0, 3.0])}, "t: holds NaN"),
    ],
)
def test_malformed_files_name_the_problem(tmp_path, change, message):
    arrays = {**good_arrays(), **change}
    arrays = {key: value for key, value in arrays.items() if value is not None}
    path = write_raw(tmp_path / "bad.npz", **arrays)
    with pytest.raises(RecordingError, match=message):
        load(path)


def test_truncated_and_garbage_files(tmp_path):
    path = save(make(), tmp_path / "r.npz")
    data = path.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match="cut.npz"):
        load(tmp_path / "cut.npz")
    (tmp_path / "text.npz").write_text("hello")
    with pytest.raises(RecordingError, match="not an .npz recording"):
        load(tmp_path / "text.npz")
    with pytest.raises(RecordingError, match="no such file"):
        load(tmp_path / "missing.npz")


def test_unknown_keys_are_ignored(tmp_path):
    path = write_raw(tmp_path / "extra.npz", **good_arrays(), exposure=np.ones(4))
    assert load(path).n_frames == 4


def test_save_is_atomic_and_leaves_no_temporary(tmp_path):
    save(make(), tmp_path / "r.npz")
    assert [p.name for p in tmp_path.iterdir()] == ["r.npz"]
    with zipfile.ZipFile(tmp_path / "r.npz") as archive:
        assert {"frames.npy", "t.npy", "reference.npy", "meta.npy"} <= set(archive.namelist())
