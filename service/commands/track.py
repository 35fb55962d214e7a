"""``graytrack track REC.npz --model MODEL.json --out TRACK.csv``."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from graytrack.service.batch.chunks import ChunkOptions, add_chunk_arguments, chunk_options

if TYPE_CHECKING:  # the parser is built for every command: only `run` imports the numerics
    import numpy as np

    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.recording import Recording
    from graytrack.core.tracking import TrackResult
    from graytrack.service.progress import ProgressBar

CSV_COLUMNS = ("t", "x_mm", "locked", "rms_gray", "crlb_um", "reference_mm", "error_um")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("track", help="solve every frame's position with a calibrated model")
    parser.add_argument("recording", help="recording (.npz) to track")
    parser.add_argument("--model", required=True, help="model file from `graytrack calibrate` or `diagnose`")
    parser.add_argument("--out", required=True, help="CSV to write; header starts t,x_mm")
    parser.add_argument("--no-reference", action="store_true",
                        help="ignore the recording's grating readout (acquire and track on the image alone)")
    add_chunk_arguments(parser)
    parser.set_defaults(func=run)


def result_columns(t: np.ndarray, result: TrackResult, reference: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "t": t, "x_mm": result.x_mm, "locked": result.locked.astype(int), "rms_gray": result.rms_gray,
        "crlb_um": result.crlb_mm * 1e3, "reference_mm": reference, "error_um": result.error_um(reference),
    }


def summary(result: TrackResult, reference: np.ndarray) -> list[str]:
    import numpy as np

    lines = [f"frames  {result.x_mm.size}, locked {int(result.locked.sum())}, lock events {len(result.events)}"]
    for event in result.events[:10]:
        state = f"re-acquired at {event.x_after_mm:.4f} mm" if event.reacquired else "not re-acquired"
        lines.append(f"  frame {event.frame}: {event.reason}; {state}")
    error = result.error_um(reference)
    if np.isfinite(error).sum() > 1:
        lines.append(
            f"error   std {np.nanstd(error):.3f} um, mean {np.nanmean(error):+.3f} um, max |e| {np.nanmax(np.abs(error)):.3f} um"
            f" (noise floor {np.nanmedian(result.crlb_mm) * 1e3:.3f} um)"
        )
    return lines


def solve(recording: Recording, model: FourierModel, no_reference: bool = False,
          progress: ProgressBar | None = None, chunks: ChunkOptions | None = None) -> tuple[TrackResult, np.ndarray]:
    """Track a recording as the command does: (result, the grating at the exposure instants)."""
    import numpy as np

    from graytrack.core.timing import at_exposure
    from graytrack.core.tracking import track
    from graytrack.service.batch.chunks import track_in_chunks

    grating = recording.reference
    skew_s = float(model.info.get("reference_skew_s", 0.0))
    if skew_s:  # the closed loop found the grating latched off mid-exposure: compare at the exposure
        grating = at_exposure(recording.t, grating, skew_s)
        print(f"grating reference moved to mid-exposure ({skew_s * 1e3:+.3f} ms, from the model)")
    reference = np.full(recording.n_frames, np.nan) if no_reference else grating
    if chunks is not None:
        return track_in_chunks(model, recording.frames, reference, chunks), grating
    return track(model, recording.frames, reference=reference, progress=progress), grating


def run(args: argparse.Namespace) -> int:
    from graytrack.core.models import load_model
    from graytrack.core.recording import load
    from graytrack.service.outputs import output_file
    from graytrack.service.progress import ProgressBar
    from graytrack.service.tables import write_csv

    chunks = chunk_options(args)
    output_file(args.out)
    recording = load(args.recording)
    model = load_model(args.model)
    result, grating = solve(recording, model, args.no_reference, ProgressBar("track"), chunks)
    path = write_csv(args.out, result_columns(recording.t, result, grating))
    print("\n".join(summary(result, grating)))
    print(f"wrote   {path}")
    return 0
