"""Long recordings tracked in chunks, each on its own worker, and stitched back into one track.

Sequential tracking carries one thing from frame to frame: which period of the target the stage
is on. A chunk that starts cold must find that out on its own: from the grating reference when
its first frame has one, otherwise by the global search over the calibrated stroke, which on a
stroke longer than a period may land one period off. Each chunk therefore starts ``overlap``
frames before the frames it answers for; on those frames it is compared with the chunk before:
the difference picks the period (a whole number of periods, exact for models periodic in x), and
whatever then still disagrees means the chunk did not settle on the sequential solution (a lock
event inside the overlap, a cold start on a frame that cannot be placed). Such a chunk is tracked
again as the plain continuation of the one before, so the stitched track is the sequential one
on every frame where both are locked; only the parallel speed is lost, never correctness.

Pure numpy on top of :func:`graytrack.core.tracking.track`; how chunks are spread over workers is
the caller's business (``map_chunks``), so this module knows nothing of Dask.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from graytrack.core.errors import TrackingError
from graytrack.core.models.fourier import FourierModel
from graytrack.core.period_rival import repeats
from graytrack.core.slide import SlideWatch, carry
from graytrack.core.tracking import LockEvent, TrackResult, track
from graytrack.core.validity import FAMILIES

DEFAULT_OVERLAP = 32
# Both chunks solve the same frames with the same solver: after the period is picked they agree to
# the Gauss–Newton tolerance. Anything beyond this is a different solution, not rounding.
AGREE_MM = 1e-5

PER_FRAME = tuple(f.name for f in dataclasses.fields(TrackResult)
                  if f.name not in ("events", "chi2_calibration", "texture", "slide_sigma_um"))  # an array per frame


@dataclass(frozen=True)
class Chunk:
    """Frames ``[start, stop)`` are tracked; the chunk answers for ``[keep, stop)``."""

    start: int
    keep: int
    stop: int


@dataclass(frozen=True)
class ChunkTask:
    """Everything a worker needs to track one chunk (only that chunk's frames travel)."""

    model: FourierModel
    frames: np.ndarray
    reference: np.ndarray
    chunk: Chunk
    x0_mm: float | None = None
    light: str | None = None  # as track(): the light mode and the robust reweighting
    robust: bool = False
    slide: bool = False  # no grating read: each bound carries the slide (core/slide.py), the axis ``axis_px`` off
    axis_px: float | None = None


@dataclass
class StitchReport:
    """How the chunks were joined: period shifts applied and chunks tracked again in sequence."""

    chunks: int
    shifted: list[tuple[int, float]] = field(default_factory=list)  # (chunk index, shift in mm)
    redone: list[tuple[int, str]] = field(default_factory=list)     # (chunk index, why)


def plan_chunks(n_frames: int, chunk_frames: int, overlap: int = DEFAULT_OVERLAP) -> list[Chunk]:
    """Chunks of ``chunk_frames`` answered frames, each starting ``overlap`` frames early."""
    if chunk_frames < 1 or overlap < 1:
        raise TrackingError(f"chunks need at least 1 frame and 1 overlap frame (got {chunk_frames}, {overlap})")
    if chunk_frames <= overlap:
        raise TrackingError(f"a chunk of {chunk_frames} frames cannot carry an overlap of {overlap}")
    keeps = list(range(0, n_frames, chunk_frames))
    if len(keeps) > 1 and n_frames - keeps[-1] < overlap:
        keeps.pop()  # a tail shorter than the overlap joins the chunk before
    stops = keeps[1:] + [n_frames]
    return [Chunk(max(keep - overlap, 0), keep, stop) for keep, stop in zip(keeps, stops)]


def chunk_task(model: FourierModel, frames: np.ndarray, reference: np.ndarray, chunk: Chunk,
               x0_mm: float | None = None, light: str | None = None, robust: bool = False,
               slide: bool = False, axis_px: float | None = None) -> ChunkTask:
    return ChunkTask(model, np.asarray(frames)[chunk.start:chunk.stop], np.asarray(reference)[chunk.start:chunk.stop],
                     chunk, x0_mm, light, robust, slide, axis_px)


def track_chunk(task: ChunkTask) -> TrackResult:
    """Track one chunk from a cold start (or from ``x0_mm``, the previous frame's position), learning
    nothing on the print: marks learned over one chunk and not the next would part their answers
    over the overlap, where the stitching holds them to agree. With ``slide`` (no grating read) the
    chunk's bounds carry the slide as ``track`` with a slide watch does, from the watch's prior at the
    chunk's first frame: its overlap frames let the watch's mean settle before the frames it answers for."""
    watch = SlideWatch.for_model(task.model, task.axis_px) if task.slide else None
    result = track(task.model, task.frames, reference=task.reference, x0_mm=task.x0_mm, light=task.light,
                   robust=task.robust, learn=False, watches=[watch] if watch is not None else [])
    if watch is not None:
        result.slide_sigma_um = carry(result, watch)["slide_sigma_um"]
    return result


def _overlap_shift(model: FourierModel, before: TrackResult, chunk: Chunk,
                   result: TrackResult) -> tuple[float, str | None]:
    """Whole-period shift that maps the chunk onto the track before it, or why it does not fit."""
    width = chunk.keep - chunk.start
    prev_x, prev_locked = before.x_mm[chunk.start:chunk.keep], before.locked[chunk.start:chunk.keep]
    both = prev_locked & result.locked[:width] & np.isfinite(prev_x) & np.isfinite(result.x_mm[:width])
    if not both.any():
        return 0.0, "no frame of the overlap is locked in both chunks"
    diff = prev_x[both] - result.x_mm[:width][both]
    shift = float(np.round(np.median(diff) / model.period_mm) * model.period_mm)
    worst = float(np.max(np.abs(diff - shift)))
    if worst > AGREE_MM:
        return shift, f"overlap disagrees by {worst * 1e3:.3f} um after the period pick"
    if shift and not repeats(model):
        return shift, f"acquired {shift:+.3f} mm off with a model that is not periodic in x"
    return shift, None


def _answered(result: TrackResult, chunk: Chunk, shift_mm: float) -> tuple[dict[str, np.ndarray], list[LockEvent]]:
    """The chunk's own frames (warm-up dropped), shifted by whole periods, events in global frames."""
    first = chunk.keep - chunk.start
    columns = {name: getattr(result, name)[first:] for name in PER_FRAME}
    if result.slide_sigma_um is not None:
        columns["slide_sigma_um"] = result.slide_sigma_um[first:]
    columns["x_mm"] = columns["x_mm"] + shift_mm
    events = [replace(event, frame=event.frame + chunk.start, x_before_mm=event.x_before_mm + shift_mm,
                      x_after_mm=event.x_after_mm + shift_mm)
              for event in result.events if event.frame >= first]
    return columns, events


def _last_position(x_mm: np.ndarray, before: int) -> float | None:
    placed = np.flatnonzero(np.isfinite(x_mm[:before]))
    return float(x_mm[placed[-1]]) if placed.size else None


MapChunks = Callable[[Sequence[ChunkTask]], Sequence[TrackResult]]


def track_chunked(model: FourierModel, frames: np.ndarray, reference: np.ndarray | None, chunk_frames: int,
                  overlap: int = DEFAULT_OVERLAP, map_chunks: MapChunks | None = None, x0_mm: float | None = None,
                  redo: Callable[[ChunkTask], TrackResult] = track_chunk, light: str | None = None,
                  robust: bool = False, slide: bool = False,
                  axis_px: float | None = None) -> tuple[TrackResult, StitchReport]:
    """Track ``frames`` in chunks (``map_chunks`` runs them, in parallel if it can) and stitch them.

    ``x0_mm`` is the first frame's start, as in :func:`track`; ``slide``: no grating is read, each
    chunk's bounds carry the slide a magnification change could give the image (``axis_px``: its lever).
    The result has the same columns as :func:`track` on the whole recording; the report says which
    chunks needed a period shift and which were tracked again as the sequential continuation.
    """
    frames = np.asarray(frames)
    n_frames = frames.shape[0]
    reference = np.full(n_frames, np.nan) if reference is None else np.asarray(reference, dtype=np.float64)
    if reference.shape != (n_frames,):
        raise TrackingError(f"reference has shape {reference.shape}, expected ({n_frames},)")
    chunks = plan_chunks(n_frames, chunk_frames, overlap)
    tasks = [chunk_task(model, frames, reference, chunk, x0_mm if chunk.start == 0 else None, light, robust, slide,
                        axis_px) for chunk in chunks]
    results = list((map_chunks or (lambda items: [track_chunk(item) for item in items]))(tasks))

    nan = lambda: np.full(n_frames, np.nan)  # noqa: E731
    stitched = TrackResult(nan(), np.zeros(n_frames, dtype=bool), nan(), nan(), np.zeros(n_frames, dtype=np.int64),
                           nan(), nan(), [], chi2=nan(), rejected_px=np.zeros(n_frames, dtype=np.int64),
                           stale=np.zeros(n_frames, dtype=bool),
                           stale_reason=np.full(n_frames, "", dtype=f"<U{max(map(len, FAMILIES))}"),
                           transient_px=np.zeros(n_frames, dtype=np.int64),
                           chi2_calibration=results[0].chi2_calibration if results else float("nan"),
                           focus_px2=nan(), focus_sigma_px2=nan(), repeated=np.zeros(n_frames, dtype=bool),
                           texture_px=np.zeros(n_frames, dtype=np.int64), slide_sigma_um=nan() if slide else None)
    report = StitchReport(len(chunks))
    for index, (chunk, result) in enumerate(zip(chunks, results)):
        shift = 0.0
        if index:
            shift, problem = _overlap_shift(model, stitched, chunk, result)
            if problem:
                report.redone.append((index, problem))
                x0 = _last_position(stitched.x_mm, chunk.keep)
                task = chunk_task(model, frames, reference, Chunk(chunk.keep, chunk.keep, chunk.stop), x0, light,
                                  robust, slide, axis_px)
                result, shift = redo(task), 0.0
                chunk = task.chunk
            elif shift:
                report.shifted.append((index, shift))
        columns, events = _answered(result, chunk, shift)
        for name, values in columns.items():
            getattr(stitched, name)[chunk.keep:chunk.stop] = values
        stitched.events.extend(events)
    return stitched, report
