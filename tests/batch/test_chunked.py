"""Chunked tracking (core/chunked.py) equals sequential tracking on every frame where both are locked."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.chunked import Chunk, plan_chunks, track_chunked
from graytrack.core.errors import TrackingError
from graytrack.core.tracking import track
from graytrack.drivers.sim import paper


def lost_lock_recording(seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Out and back over 9 mm (more than a period), a 3 mm jump on the way back and one garbage frame."""
    x_mm = np.concatenate([np.linspace(0.5, 9.5, 300), np.linspace(9.5, 0.5, 300)])
    x_mm[400:] -= 3.0
    frames = paper.paper_frames(x_mm, rng=np.random.default_rng(seed))[:, 0, :].astype(np.float32)
    frames[250] = np.random.default_rng(0).uniform(0, 255, frames.shape[1])
    return frames, x_mm


def assert_equal_where_locked(sequential, chunked) -> None:
    both = sequential.locked & chunked.locked
    assert both.sum() >= 0.95 * both.size
    assert np.max(np.abs(sequential.x_mm[both] - chunked.x_mm[both])) < 1e-6  # 1 nm
    assert [e.frame for e in chunked.events] == [e.frame for e in sequential.events]


@pytest.mark.parametrize("with_reference", [True, False])
def test_chunked_equals_sequential_through_lost_lock(paper_models, with_reference):
    model = paper_models["paper"].model
    frames, x_mm = lost_lock_recording()
    reference = x_mm if with_reference else np.full(x_mm.size, np.nan)
    sequential = track(model, frames, reference=reference)
    assert {e.frame for e in sequential.events} >= {250, 400}  # the recording does lose lock
    chunked, report = track_chunked(model, frames, reference, chunk_frames=64, overlap=16)
    assert_equal_where_locked(sequential, chunked)
    assert report.chunks == 10 and not report.redone
    if not with_reference:
        # cold starts on a 10.4 mm stroke land a period off at times; the overlap put them back
        assert report.shifted and all(abs(abs(s) - model.period_mm) < 1e-9 for _, s in report.shifted)
    assert np.nanmax(np.abs(chunked.error_um(x_mm) - sequential.error_um(x_mm))) < 1e-3


def test_a_chunk_whose_overlap_cannot_be_checked_is_tracked_as_the_continuation(paper_models):
    model = paper_models["paper"].model
    frames, x_mm = lost_lock_recording()
    frames[172:196] = np.random.default_rng(1).uniform(0, 255, (24, frames.shape[1]))  # covers chunk 3's overlap
    sequential = track(model, frames)
    chunked, report = track_chunked(model, frames, None, chunk_frames=64, overlap=16)
    assert [index for index, _ in report.redone] == [3]
    assert "no frame of the overlap" in report.redone[0][1]
    assert_equal_where_locked(sequential, chunked)


def test_parallel_map_gets_every_chunk_once(paper_models):
    model = paper_models["paper"].model
    frames, x_mm = lost_lock_recording()
    seen = []

    def map_chunks(tasks):
        seen.extend(task.chunk for task in tasks)
        assert all(task.frames.shape[0] == task.chunk.stop - task.chunk.start for task in tasks)
        return [track(t.model, t.frames, reference=t.reference, x0_mm=t.x0_mm) for t in reversed(tasks)][::-1]

    chunked, _ = track_chunked(model, frames, x_mm, chunk_frames=200, overlap=20, map_chunks=map_chunks)
    assert seen == [Chunk(0, 0, 200), Chunk(180, 200, 400), Chunk(380, 400, 600)]
    assert_equal_where_locked(track(model, frames, reference=x_mm), chunked)


def test_plan_chunks():
    assert plan_chunks(100, 40, 10) == [Chunk(0, 0, 40), Chunk(30, 40, 80), Chunk(70, 80, 100)]
    assert plan_chunks(100, 40, 25) == [Chunk(0, 0, 40), Chunk(15, 40, 100)]  # a 20-frame tail is too short alone
    assert plan_chunks(30, 40, 10) == [Chunk(0, 0, 30)]
    with pytest.raises(TrackingError, match="overlap"):
        plan_chunks(100, 10, 10)
