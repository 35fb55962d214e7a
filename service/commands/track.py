"""``graytrack track REC.npz --model MODEL.json --out TRACK.csv``."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from typing import TYPE_CHECKING

from graytrack.service.batch.chunks import ChunkOptions, add_chunk_arguments, chunk_options

if TYPE_CHECKING:  # the parser is built for every command: only `run` imports the numerics
    import numpy as np

    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.recording import Recording
    from graytrack.core.slide import SlideWatch
    from graytrack.core.tracking import TrackResult
    from graytrack.core.watches.scale import ScaleWatch
    from graytrack.service.progress import NoteCallback, ProgressBar


def csv_columns() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(every column of the contract's CSV, the frame record's ones after the grating's), from the record;
    texture_px follows them with learning on. (A function: the parser is built without graytrack.core.)"""
    from graytrack.core.frame_record import PLACEMENT, QUANTITIES

    tail = tuple(q.name for q in QUANTITIES if q.csv and q.name not in PLACEMENT and q.name != "texture_px")
    return ("t", *PLACEMENT, "reference_mm", "error_um", *tail), tail


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("track", help="solve every frame's position with a calibrated model")
    parser.add_argument("recording", help="recording (.npz) to track")
    parser.add_argument("--model", required=True, help="model file from `graytrack calibrate` or `diagnose`")
    parser.add_argument("--out", required=True, help="CSV to write; header starts t,x_mm")
    parser.add_argument("--no-reference", action="store_true",
                        help="ignore the recording's grating readout (acquire and track on the image alone)")
    parser.add_argument("--light", choices=("auto", "fixed", "free"), default="auto",
                        help="per-frame light gain/offset: solved when a frame's residual asks for it (auto, default), "
                             "never (fixed: the calibration's light), or always (free)")
    parser.add_argument("--no-robust", action="store_true",
                        help="do not set aside pixels that went bad in this run (robust reweighting is on by default)")
    parser.add_argument("--trim", action="store_true",
                        help="correct scale and offset against the recording's grating as the daemon's online trim "
                             "would (only on evidence of a drift; columns trim_um, trim_sigma_um)")
    parser.add_argument("--axis-px", type=float, default=None, metavar="PX",
                        help="the optical axis's distance from the ROI's centre along the line, pixels (the camera's "
                             "geometry): without a grating each bound carries what a magnification change could "
                             "slide the image by (column slide_sigma_um; default 300, a prior; 0: the ROI on the axis)")
    parser.add_argument("--mains-hz", type=float, default=None, metavar="HZ",
                        help="--engine estimator: the mains frequency the rig's lamp runs on, whose flicker at twice "
                             "it the estimator follows (default: the recording's mains_hz, else 50; 60 where the grid "
                             "is; 0: a lamp on DC)")
    parser.add_argument("--flip", action="store_true",
                        help="reverse the pixel axis first (default: when the model was calibrated with --flip)")
    parser.add_argument("--engine", choices=("watches", "estimator"), default="watches",
                        help="the per-frame path: today's solver with its watches (default), or the one recursive "
                             "estimator (core/estimator/: every nuisance a state with a declared rate, flags from one "
                             "innovation test; --trim fuses the grating, --no-reference reads none)")
    add_chunk_arguments(parser)
    parser.set_defaults(func=run)


def oriented(recording: Recording, model: FourierModel, flip: bool, *, note: NoteCallback) -> Recording:
    """The recording as the model expects it. ``--flip`` reverses the pixel axis; without it, a model
    calibrated with ``--flip`` reverses the frames of its camera likewise, unless the recording says
    its frames were reversed already (by ``[camera] flip`` or a tool); each is said to ``note``."""
    from graytrack.core.recording import PIXEL_AXIS_REVERSED

    if flip:
        note("flip    pixel axis reversed (--flip)")
        return recording.flipped()
    if model.info.get("flip") and not recording.meta.get(PIXEL_AXIS_REVERSED):
        note("flip    pixel axis reversed: the model was calibrated with --flip")
        return recording.flipped()
    return recording


def result_columns(t: np.ndarray, result: TrackResult, reference: np.ndarray) -> dict[str, np.ndarray]:
    """The CSV's columns (docs/contracts.md): time, the frame record's quantities in the contract's
    order, the grating and the error against it; with learning on, the samples a mark learned on
    the print corrected (``texture_px``, core/texture.py)."""
    from graytrack.core import frame_record

    record = frame_record.columns(result)
    head = {"t": t, **{name: record[name] for name in frame_record.PLACEMENT},
            "reference_mm": reference, "error_um": result.error_um(reference)}
    learned = {"texture_px": record["texture_px"]} if result.texture is not None else {}
    return {**head, **{name: record[name] for name in csv_columns()[1]}, **learned}


def summary(result: TrackResult, reference: np.ndarray) -> list[str]:
    import numpy as np

    lines = [f"frames  {result.x_mm.size}, locked {int(result.locked.sum())}, lock events {len(result.events)}"]
    for event in result.events[:10]:
        if not event.lost:
            lines.append(f"  frame {event.frame}: {event.reason}")
            continue
        state = f"re-acquired at {event.x_after_mm:.4f} mm" if event.reacquired else "not re-acquired"
        lines.append(f"  frame {event.frame}: {event.reason}; {state}")
    error = result.error_um(reference)
    if np.isfinite(error).sum() > 1:
        lines.append(
            f"error   std {np.nanstd(error):.3f} um, mean {np.nanmean(error):+.3f} um, max |e| "
            f"{np.nanmax(np.abs(error)):.3f} um"
            f" (noise floor {np.sqrt(np.nanmean(np.square(result.crlb_mm))) * 1e3:.3f} um, "
            "the rms of the frames' bounds)"
        )
    lines.extend(validity(result))
    return lines


def validity(result: TrackResult) -> list[str]:
    """How well the model still describes the images: χ², rejected pixels, light, and staleness."""
    import numpy as np

    chi2 = result.chi2[np.isfinite(result.chi2)]
    if not chi2.size:
        return []
    lines = [f"model   chi2 per pixel median {np.median(chi2):.2f} (calibration {result.chi2_calibration:.2f}); "
             f"frames with rejected pixels {int((result.rejected_px > 0).sum())}, "
             f"with the light re-solved {int((np.isfinite(result.gain) & (result.gain != 1.0)).sum())}"]
    return lines


def stale_warning(result: TrackResult) -> str | None:
    """One line for stderr when the model went stale during the run (sustained χ² rise)."""
    import numpy as np

    from graytrack.core.validity import ADVICE

    if not result.stale.any():
        return None
    stale = result.stale
    alone = stale & ~np.concatenate([[False], stale[:-1]]) & ~np.concatenate([stale[1:], [False]])
    if (stale == alone).all() and stale.sum() <= max(3, 0.01 * stale.size):
        # A few frames flagged one at a time, each between unflagged ones: no model gone stale, but
        # single frames on which camera and grating (or the image) disagreed; a family's advice
        # (recalibrate) would be the wrong one
        frames = np.flatnonzero(stale)
        listed = ", ".join(str(k) for k in frames[:8]) + (f" and {frames.size - 8} more" if frames.size > 8 else "")
        return (f"warning: {frames.size} single frame(s) flagged, each between unflagged ones (frame {listed}): "
                f"a grating reading gone wrong or a frame placed wrong there (see stale_reason), not the model")
    first = int(np.argmax(stale))
    families, counts = np.unique(result.stale_reason[result.stale], return_counts=True)
    causes = ", ".join(f"{family} ({count} frames)" for family, count in sorted(zip(families, counts),
                                                                               key=lambda item: -item[1]))
    return (f"warning: model stale on {int(result.stale.sum())} of {result.stale.size} frames from frame {first} on, "
            f"for {causes}: {ADVICE[str(families[np.argmax(counts)])]}")



def texture_lines(result: TrackResult, out: str) -> list[str]:
    """What the run learned on the print (core/texture.py): a line, and the marks as JSON beside
    the CSV (``TRACK.texture.json``: where each mark is, how deep, how sure, and the events)."""
    import json
    from pathlib import Path

    from graytrack.core.jsonable import finite_or_none
    from graytrack.core.texture import summary_line

    if result.texture is None:
        return []
    path = Path(out).with_suffix(".texture.json")
    path.write_text(json.dumps(finite_or_none(result.texture), indent=1, allow_nan=False) + "\n")
    return [f"{summary_line(result.texture)} ({path})"]


def refuse_mismatched(recording: Recording, model: FourierModel) -> None:
    """Raises TrackingError where the frames cannot be the model's: read out on another range than its calibration's
    (a camera's pixel format changed since), or reversed against it (:func:`refuse_reversed`)."""
    from graytrack.core.calibration_data import readout_mismatch
    from graytrack.core.errors import TrackingError

    mismatch = readout_mismatch(model.info, recording.meta)
    if mismatch is not None:
        raise TrackingError(f"{mismatch}; recalibrate with the camera as it is now, or set its pixel format back")
    refuse_reversed(recording, model)


def refuse_reversed(recording: Recording, model: FourierModel) -> None:
    """Raises TrackingError where the frames fit the model far better reversed at the grating's positions (a camera
    remounted since calibration, ReverseX toggled, ``--flip`` given twice or forgotten): either engine would track
    them millimetres off, flagged on most frames but not all (the estimator from the image alone: 129 of 500 frames
    of a mirrored print 4+ bounds off unflagged). Read whether or not the run tracks with the grating."""
    from graytrack.core.errors import TrackingError
    from graytrack.core.geometry_check import FLIP_GAIN, orientation_mismatch

    mismatch = orientation_mismatch(model, recording)
    if mismatch is not None and mismatch >= FLIP_GAIN:
        raise TrackingError(f"the frames look reversed against the model: at the grating's positions they fit it "
                            f"{mismatch:.0f}x better reversed; track with --flip, or without it when the frames were "
                            f"reversed already (model calibrated with --flip: {bool(model.info.get('flip'))})")


def solve(recording: Recording, model: FourierModel, no_reference: bool = False,
          progress: ProgressBar | None = None, chunks: ChunkOptions | None = None, light: str = "auto",
          robust: bool = True, trim: bool = False, slide: "SlideWatch | None" = None, *,
          note: NoteCallback) -> tuple[TrackResult, np.ndarray, "ScaleWatch | None"]:
    """Track a recording as the command does: (result, the grating at the exposure instants, the
    tracker's scale watch: with ``trim``, it carries the online trim; see track_scale.py); what it did
    besides (the grating moved to mid-exposure, the chunks' period picks) is said to ``note``. ``slide``:
    where no grating is read, the watch that keeps each frame's slide σ (core/slide.py; in chunks each chunk's
    tracker carries one of its own with the same lever: the result's ``slide_sigma_um``).

    ``recording`` is oriented already (:func:`oriented`); frames that fit the model far better
    reversed, or read out on another range than the model's, are refused here (:func:`refuse_mismatched`), before a
    run tracked millimetres off."""
    import numpy as np

    refuse_mismatched(recording, model)

    from graytrack.core.timing import model_reference
    from graytrack.core.tracking import track
    from graytrack.service.batch.chunks import track_in_chunks

    grating = recording.reference
    skew_s = float(model.info.get("reference_skew_s", 0.0))
    if skew_s:  # the closed loop found the grating latched off mid-exposure: compare at the exposure
        grating = model_reference(model, recording.t, grating)
        note(f"grating reference moved to mid-exposure ({skew_s * 1e3:+.3f} ms, from the model)")
    from graytrack.service.commands.track_scale import scale_watch

    reference = np.full(recording.n_frames, np.nan) if no_reference else grating
    watch = scale_watch(recording, model, reference, trim)
    if chunks is not None:  # the chunks' own trackers: the watch follows their positions afterwards (check)
        axis_px = slide.lever_mm / model.pixel_pitch_mm if slide is not None and slide.declared else None
        return track_in_chunks(model, recording.frames, reference, chunks, light, robust, slide is not None,
                               axis_px, note=note), grating, watch
    return track(model, recording.frames, reference=reference, progress=progress, light=light, robust=robust,
                 learn=robust, watches=[given for given in (watch, slide) if given is not None]), grating, watch


def slide_for(recording: Recording, model: FourierModel, no_reference: bool,
              axis_px: float | None = None) -> "SlideWatch | None":
    """The slide watch whose σ each bound carries where no grating vouches for the positions (core/slide.py):
    ``--no-reference``, or a recording without a grating reading; None with one."""
    import numpy as np

    from graytrack.core.slide import SlideWatch

    unread = no_reference or not np.isfinite(recording.reference).any()
    return SlideWatch.for_model(model, axis_px) if unread else None


def run(args: argparse.Namespace) -> int:
    from graytrack.core.models import load_model
    from graytrack.core.recording import load
    from graytrack.service.outputs import output_file
    from graytrack.service.progress import ProgressBar
    from graytrack.core.slide import carry, describe
    from graytrack.service.commands.track_scale import check
    from graytrack.service.tables import write_csv

    from graytrack.service.blas import single_threaded_blas

    single_threaded_blas()  # frame-sized products: a second BLAS thread only spins (service/blas.py)
    chunks = chunk_options(args)
    if args.mains_hz is not None and args.engine != "estimator":
        from graytrack.service.errors import CliError

        raise CliError("--mains-hz: only the estimator follows a lamp's flicker (add --engine estimator)")
    output_file(args.out)
    recording = load(args.recording)
    model = load_model(args.model)
    recording = oriented(recording, model, args.flip, note=print)
    if args.engine == "estimator":
        refuse_mismatched(recording, model)  # (today's path refuses them in solve)
        return run_estimator(args, recording, model)
    slide = slide_for(recording, model, args.no_reference, args.axis_px)  # no grating vouches: the slide
    result, grating, watch = solve(recording, model, args.no_reference, ProgressBar("track"), chunks, args.light,
                                   not args.no_robust, args.trim, slide, note=print)
    scale = check(recording, model, result, args.trim, watch)
    slid = carry(result, slide) if result.slide_sigma_um is None else {"slide_sigma_um": result.slide_sigma_um}
    path = write_csv(args.out, {**result_columns(recording.t, result, grating), **slid, **scale.columns})
    said = describe(slide.lever_mm, slide.declared, slid) if slide is not None else []
    print("\n".join(summary(result, grating) + said + scale.lines + texture_lines(result, args.out)))
    from graytrack.core.geometry_check import refusal

    if refusal(model):
        print(f"warning: the model's calibration refused its geometry ({refusal(model)}): no frame is called locked",
              file=sys.stderr)
    for warning in (stale_warning(result), scale.warning):
        if warning:
            print(warning, file=sys.stderr)
    print(f"wrote   {path}")
    return 0


def estimated(recording: Recording, model: FourierModel, no_reference: bool = False, trim: bool = False,
              robust: bool = True, axis_px: float | None = None,
              progress: ProgressBar | None = None) -> tuple[TrackResult, np.ndarray]:
    """Track a recording with the one recursive estimator (core/estimator/): (result, the grating at the
    exposure instants). The grating is checked by default, fused with ``trim``, unread with ``no_reference``."""
    import numpy as np

    from graytrack.core.estimator import as_result, calibration_level, track
    from graytrack.core.estimator.settings import EstimatorSettings
    from graytrack.core.recording import acceleration_phases
    from graytrack.core.timing import model_reference

    grating = recording.reference
    if float(model.info.get("reference_skew_s", 0.0)):
        grating = model_reference(model, recording.t, grating)
    mode = "none" if no_reference or not np.isfinite(grating).any() else ("fuse" if trim else "check")
    estimates = track(model, recording.frames, recording.t, grating, grating=mode, robust=robust, axis_px=axis_px,
                      settings=EstimatorSettings().for_recording(recording.meta), progress=progress,
                      stage_phases=acceleration_phases(recording.meta))
    return as_result(estimates, calibration_level(model)), grating


def run_estimator(args: argparse.Namespace, recording: Recording, model: FourierModel) -> int:
    """``track --engine estimator``: the same CSV, its bound the posterior σ with every nuisance."""
    from graytrack.service.progress import ProgressBar
    from graytrack.service.tables import write_csv

    from graytrack.core.slide import AXIS_PRIOR_PX, describe

    from graytrack.core.recording import MAINS_HZ
    from graytrack.service.errors import CliError
    from graytrack.core.collector import collector_paused

    if args.mains_hz is not None:
        if not (math.isfinite(args.mains_hz) and args.mains_hz >= 0):
            raise CliError(f"--mains-hz {args.mains_hz:g}: must be a frequency of 0 or more (Hz)")
        recording = dataclasses.replace(recording, meta={**recording.meta, MAINS_HZ: float(args.mains_hz)})
    with collector_paused():
        result, grating = estimated(recording, model, args.no_reference, args.trim, not args.no_robust, args.axis_px,
                                    ProgressBar("track"))
        slid = {} if result.slide_sigma_um is None else {"slide_sigma_um": result.slide_sigma_um}
        path = write_csv(args.out, {**result_columns(recording.t, result, grating), **slid})
    lever_px = AXIS_PRIOR_PX if args.axis_px is None else abs(args.axis_px)
    print("\n".join(summary(result, grating) + describe(lever_px * model.pixel_pitch_mm, args.axis_px is not None,
                                                           slid)))
    warning = stale_warning(result)
    if warning:
        print(warning, file=sys.stderr)
    print(f"wrote   {path}")
    return 0
