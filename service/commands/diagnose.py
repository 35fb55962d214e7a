"""``graytrack diagnose CAL.npz [--validate VAL.npz] --out DIR``: the closed loop."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "diagnose", help="closed loop: find what the model misses, add it, report held-out error before and after")
    parser.add_argument("recording", help="calibration recording (.npz) with a grating reference")
    parser.add_argument("--validate", help="separate validation recording of the same rig (default: held-out blocks)")
    parser.add_argument("--out", required=True, help="folder for report.json, report.html and model.json")
    from graytrack.service.commands.calibrate import add_flip_argument

    add_flip_argument(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from graytrack.core.recording import load
    from graytrack.service.calibration_run import calibrate_recording, write_files
    from graytrack.service.progress import ProgressBar
    from graytrack.service.outputs import output_folder

    output_folder(args.out)
    from graytrack.service.commands.calibrate import flip_for_calibration, mark_flip

    calibration = flip_for_calibration(load(args.recording), args.flip)
    validation = load(args.validate) if args.validate else None
    if validation is not None and args.flip:
        validation = validation.flipped()
    run_ = calibrate_recording(calibration, "auto", validation=validation, progress=ProgressBar("diagnose"))
    mark_flip(run_.model, args.flip)
    paths = write_files(run_, args.out)
    print("\n".join(run_.lines()))
    print(f"wrote   {', '.join(str(path) for path in paths.values())}")
    run_.raise_if_refused()  # the report is written; the exit status says it is no success
    return 0
