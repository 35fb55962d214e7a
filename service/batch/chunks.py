"""``graytrack track --chunk-frames F``: a long recording tracked in chunks on a Dask cluster.

The chunking and the stitching are core numerics (core/chunked.py); this module only hands the
chunks to Dask's workers and says how the stitching went.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import TYPE_CHECKING

from graytrack.service.batch.cluster import add_cluster_arguments, dask_client, distributed_module

if TYPE_CHECKING:  # the parser is built for every command: the numerics load when chunks are tracked
    import numpy as np

    from graytrack.core.chunked import ChunkTask
    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.tracking import TrackResult
    from graytrack.service.progress import NoteCallback


@dataclass(frozen=True)
class ChunkOptions:
    chunk_frames: int
    overlap: int | None = None  # None: the core's default
    scheduler: str | None = None
    workers: int | None = None


def add_chunk_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--chunk-frames", type=int, default=None, metavar="F",
                        help="track in chunks of F frames in parallel on Dask (graytrack[cluster]); "
                             "the result equals sequential tracking on every frame where both are locked")
    parser.add_argument("--overlap", type=int, default=None, metavar="N",
                        help="frames each chunk starts early, checked against the chunk before (default 32)")
    add_cluster_arguments(parser)


def chunk_options(args: argparse.Namespace) -> ChunkOptions | None:
    """The chunking asked for, if any (checked for Dask before any file is read)."""
    if not args.chunk_frames:
        return None
    distributed_module()
    return ChunkOptions(args.chunk_frames, args.overlap, args.scheduler, args.workers)


def track_in_chunks(model: FourierModel, frames: np.ndarray, reference: np.ndarray,
                    options: ChunkOptions, light: str | None = None, robust: bool = False, slide: bool = False,
                    axis_px: float | None = None, *, note: NoteCallback) -> TrackResult:
    """The recording tracked in chunks on a Dask cluster and stitched; the stitching's picks are said to
    ``note``."""
    from graytrack.core.chunked import DEFAULT_OVERLAP, track_chunk, track_chunked

    overlap = DEFAULT_OVERLAP if options.overlap is None else options.overlap
    with dask_client(options.scheduler, options.workers) as client:
        def map_chunks(tasks: list[ChunkTask]) -> list[TrackResult]:
            return client.gather(client.map(track_chunk, tasks, pure=False))

        result, report = track_chunked(model, frames, reference, options.chunk_frames, overlap, map_chunks,
                                       light=light, robust=robust, slide=slide, axis_px=axis_px)
    shifts = ", ".join(f"chunk {index} {shift:+.4f} mm" for index, shift in report.shifted) or "none"
    note(f"chunks  {report.chunks} of {options.chunk_frames} frames (overlap {overlap}); period picks: {shifts}")
    for index, why in report.redone:
        note(f"  chunk {index} tracked again as the sequential continuation: {why}")
    return result
