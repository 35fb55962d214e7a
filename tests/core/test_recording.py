"""The recording file contract: round trips, and a one-line refusal naming the key for bad files."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from graytrack.core.recording import Recording, RecordingError, load, save


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
