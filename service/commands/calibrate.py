"""``graytrack calibrate REC.npz --model {ideal,paper} --out MODEL.json``."""

from __future__ import annotations

import argparse
import math
import sys
from typing import TYPE_CHECKING

from graytrack.service.errors import CliError
from graytrack.service.outputs import output_file

if TYPE_CHECKING:
    from graytrack.core.recording import Recording

MODEL_KINDS = ("ideal", "paper", "auto")
DEFAULT_PIXEL_DEGREE = 3
PIXELS_PER_POLY_COEFF = 10  # a degree-P polynomial over n pixels fits (P+1)/n of the noise: keep it under 10 %
DATA_PER_COEFF = 10  # gray values per model coefficient, at least


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("calibrate", help="fit a gray-level model against the recording's reference")
    parser.add_argument("recording", help="calibration recording (.npz) with a grating reference")
    parser.add_argument("--model", choices=MODEL_KINDS, default="paper",
                        help="ideal = 5-parameter sine; paper = Fourier order 5 x cubic in u (default); "
                             "auto = the closed loop (graytrack diagnose) picks the effects the data need")
    parser.add_argument("--out", required=True, help="model file to write (JSON)")
    parser.add_argument("--validate", help="separate validation recording of the same rig for the held-out error "
                                           "(default: two-fold by block of the recording itself)")
    parser.add_argument("--harmonics", type=int, default=None, help="Fourier order M of the paper model (default 5)")
    parser.add_argument("--pixel-degree", type=int, default=None, help="polynomial degree P in u (default 3)")
    parser.add_argument("--rows", choices=("auto", "mean", "each"), default="auto",
                        help="multi-row strips: average rows, model each row, or decide from the data")
    add_flip_argument(parser)
    parser.set_defaults(func=run)


def add_flip_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--flip", action="store_true",
                        help="reverse the pixel axis first (a camera whose u runs against the target coordinate: "
                             "mounted the other way round, or ReverseX); the model says so, and track follows it")


def flip_for_calibration(recording: "Recording", flip: bool) -> "Recording":
    """The recording as the model will see it (reversed with ``--flip``, said on stdout)."""
    if not flip:
        return recording
    print("flip    pixel axis reversed (--flip): the model describes the reversed frames")
    return recording.flipped()


def mark_flip(model, flip: bool) -> None:
    """Record ``--flip`` in the model's info: ``track`` reverses this camera's frames likewise."""
    if flip:
        model.info["flip"] = True


def model_size_limits(recording: "Recording", pixel_degree: int) -> tuple[int, str, int, str]:
    """The largest harmonics and pixel degree this recording can support, each with its reason."""
    import numpy as np

    from graytrack.core.recording import describe_bytes, memory_budget_bytes

    n_pixels = recording.n_pixels
    max_degree = max(0, n_pixels // PIXELS_PER_POLY_COEFF - 1)
    degree_reason = (f"{n_pixels} pixels support a polynomial of degree {max_degree} at most "
                     f"({PIXELS_PER_POLY_COEFF} pixels per coefficient; more fits the noise)")
    data = int(np.isfinite(recording.reference).sum()) * n_pixels * recording.n_rows
    terms = pixel_degree + 1
    limits = [((data // (DATA_PER_COEFF * terms) - 1) // 2,
               f"{data} gray values with a reference determine {data // DATA_PER_COEFF} coefficients at most "
               f"({DATA_PER_COEFF} values each), and the model has {2 * terms} per harmonic")]
    budget = memory_budget_bytes()
    limits.append(((budget // (8 * max(data, 1) * terms) - 1) // 2,
                   f"the fit's design matrix must stay within the memory budget of {describe_bytes(budget)}"))
    period, pitch = recording.meta.get("period_mm"), recording.meta.get("pixel_pitch_mm")
    if period and pitch:
        limits.append((math.floor(period / (2 * pitch)),
                       f"a period of {period:g} mm sampled every {pitch:g} mm aliases above that harmonic"))
    max_harmonics, harmonics_reason = min(limits, key=lambda item: item[0])
    return max(max_harmonics, 0), harmonics_reason, max_degree, degree_reason


def check_model_size(recording: "Recording", harmonics: int | None, pixel_degree: int | None) -> None:
    """Refuse a model larger than the data can determine, before minutes of fitting."""
    if harmonics is not None and harmonics < 1:
        raise CliError(f"--harmonics {harmonics}: must be at least 1")
    if pixel_degree is not None and pixel_degree < 0:
        raise CliError(f"--pixel-degree {pixel_degree}: must be 0 or more")
    degree = DEFAULT_PIXEL_DEGREE if pixel_degree is None else pixel_degree
    max_harmonics, harmonics_reason, max_degree, degree_reason = model_size_limits(recording, degree)
    if pixel_degree is not None and pixel_degree > max_degree:
        raise CliError(f"--pixel-degree {pixel_degree}: at most {max_degree} here; {degree_reason}")
    if harmonics is not None and harmonics > max_harmonics:
        raise CliError(f"--harmonics {harmonics}: at most {max_harmonics} here; {harmonics_reason}")


def run(args: argparse.Namespace) -> int:
    from graytrack.core.models import save_model
    from graytrack.core.recording import load
    from graytrack.service.calibration_run import calibrate_recording
    from graytrack.service.progress import ProgressBar

    out = output_file(args.out)
    recording = flip_for_calibration(load(args.recording), args.flip)
    validation = load(args.validate) if args.validate else None
    if validation is not None and args.flip:
        validation = validation.flipped()
    check_model_size(recording, args.harmonics, args.pixel_degree)
    label = "calibrate auto" if args.model == "auto" else "calibrate"
    run_ = calibrate_recording(recording, args.model, validation=validation, harmonics=args.harmonics,
                               pixel_degree=args.pixel_degree,
                               rows=args.rows, info={"flip": True} if args.flip else None, progress=ProgressBar(label))
    run_.raise_if_refused()
    path = save_model(run_.model, out)
    print("\n".join(run_.lines()))
    print(f"wrote   {path}")
    for line in run_.warnings():
        print(line, file=sys.stderr)
    return 0
