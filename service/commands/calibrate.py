"""``graytrack calibrate REC.npz --model {ideal,paper} --out MODEL.json``."""

from __future__ import annotations

import argparse
import sys

MODEL_KINDS = ("ideal", "paper", "auto")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("calibrate", help="fit a gray-level model against the recording's reference")
    parser.add_argument("recording", help="calibration recording (.npz) with a grating reference")
    parser.add_argument("--model", choices=MODEL_KINDS, default="paper",
                        help="ideal = 5-parameter sine; paper = Fourier order 5 x cubic in u (default); "
                             "auto = the closed loop (graytrack diagnose) picks the effects the data need")
    parser.add_argument("--out", required=True, help="model file to write (JSON)")
    parser.add_argument("--harmonics", type=int, default=None, help="Fourier order M of the paper model (default 5)")
    parser.add_argument("--pixel-degree", type=int, default=None, help="polynomial degree P in u (default 3)")
    parser.add_argument("--rows", choices=("auto", "mean", "each"), default="auto",
                        help="multi-row strips: average rows, model each row, or decide from the data")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from graytrack.core.calibration import calibrate
    from graytrack.core.models import save_model
    from graytrack.core.recording import load
    from graytrack.service.progress import ProgressBar

    recording = load(args.recording)
    if args.model == "auto":
        return run_auto(recording, args.out)
    result = calibrate(recording, args.model, harmonics=args.harmonics, pixel_degree=args.pixel_degree,
                       rows=args.rows, progress=ProgressBar("calibrate"))
    path = save_model(result.model, args.out)
    print(f"model   {result.model.describe()}")
    print(f"rmse    {result.rmse_gray:.4f} gray (noise sigma {result.sigma_gray:.4f} gray from the data)")
    print(f"wrote   {path}", file=sys.stdout)
    return 0


def run_auto(recording, out: str) -> int:
    """The closed loop's final model, with its held-out figures as the summary."""
    from graytrack.core.diagnosis import diagnose
    from graytrack.core.models import save_model
    from graytrack.service.commands.diagnose import summary_lines
    from graytrack.service.progress import ProgressBar

    result = diagnose(recording, progress=ProgressBar("calibrate auto"))
    path = save_model(result.final_model, out)
    print("\n".join(summary_lines(result.report())))
    print(f"wrote   {path}")
    return 0
