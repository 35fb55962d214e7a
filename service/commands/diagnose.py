"""``graytrack diagnose CAL.npz [--validate VAL.npz] --out DIR``: the closed loop."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "diagnose", help="closed loop: find what the model misses, add it, report held-out error before and after")
    parser.add_argument("recording", help="calibration recording (.npz) with a grating reference")
    parser.add_argument("--validate", help="separate validation recording of the same rig (default: held-out blocks)")
    parser.add_argument("--out", required=True, help="folder for report.json, report.html and model.json")
    parser.set_defaults(func=run)


def _figure(value: float | None, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _figures(entry: dict) -> str:
    lost = f", {entry['lost_frames']} frame(s) not tracked" if entry.get("lost_frames") else ""
    return f"rmse {_figure(entry['rmse_gray'], 4)} gray, error std {_figure(entry['error_std_um'], 3)} um{lost}"


def summary_lines(report: dict) -> list[str]:
    before, after, noise = report["before"], report["after"], report["noise"]
    lines = [f"before  {before['model']}: {_figures(before)}"]
    for step in report["steps"]:
        lines.append(f"  + {step['effect']:<16} {step['evidence']}")
        lines.append(f"    {'':<16} {_figures(step)}")
    lines.append(f"after   {after['model']}: {_figures(after)}")
    lines.append(f"noise   sigma {_figure(noise['gray'], 4)} gray, Cramer-Rao bound {_figure(noise['crlb_um'], 3)} um")
    if noise.get("reference_resolution_um"):
        lines.append(f"        grating readout in steps of {noise['reference_resolution_um']:.3f} um: "
                     f"floor against it {_figure(noise['floor_um'], 3)} um")
    return lines


def run(args: argparse.Namespace) -> int:
    from graytrack.core.diagnosis import diagnose
    from graytrack.core.recording import load
    from graytrack.service.progress import ProgressBar
    from graytrack.service.outputs import output_folder
    from graytrack.service.report import write_report

    output_folder(args.out)
    calibration = load(args.recording)
    validation = load(args.validate) if args.validate else None
    result = diagnose(calibration, validation, progress=ProgressBar("diagnose"))
    paths = write_report(result, args.out)
    print("\n".join(summary_lines(result.report())))
    print(f"wrote   {paths['json']}, {paths['html']}, {paths['model']}")
    return 0
