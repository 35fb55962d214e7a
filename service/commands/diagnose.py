"""``graytrack diagnose CAL.npz [--validate VAL.npz] --out DIR``: the closed loop."""

from __future__ import annotations

import argparse

from graytrack.service.figures import positive, shown


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "diagnose", help="closed loop: find what the model misses, add it, report held-out error before and after")
    parser.add_argument("recording", help="calibration recording (.npz) with a grating reference")
    parser.add_argument("--validate", help="separate validation recording of the same rig (default: held-out blocks)")
    parser.add_argument("--out", required=True, help="folder for report.json, report.html and model.json")
    from graytrack.service.commands.calibrate import add_flip_argument

    add_flip_argument(parser)
    parser.set_defaults(func=run)


def _figure(value: float | None, digits: int) -> str:
    return shown(value, digits, missing="n/a")  # the terminal gets ASCII


def _figures(entry: dict) -> str:
    lost = f", {_figure(entry['lost_frames'], 0)} frame(s) not tracked" if entry.get("lost_frames") else ""
    return f"rmse {_figure(entry['rmse_gray'], 4)} gray, error std {_figure(entry['error_std_um'], 3)} um{lost}"


def geometry_lines(report: dict) -> list[str]:
    """The geometry check first: a refusal, or the likely causes of a doubt."""
    check = report.get("geometry") or {}
    if check.get("status") == "refused":
        return [f"REFUSED {check['message']} (the loop stopped; no model written)"]
    return [f"warning {text}" for text in check.get("warnings") or []] if check.get("status") == "doubtful" else []


def summary_lines(report: dict) -> list[str]:
    before, after, noise = report["before"], report["after"], report["noise"]
    lines = geometry_lines(report) + [f"before  {before['model']}: {_figures(before)}"]
    for step in report["steps"]:
        lines.append(f"  + {step['effect']:<16} {step['evidence']}")
        lines.append(f"    {'':<16} {_figures(step)}")
    lines.append(f"after   {after['model']}: {_figures(after)}")
    lines.append(f"noise   sigma {_figure(noise['gray'], 4)} gray, Cramer-Rao bound {_figure(noise['crlb_um'], 3)} um")
    compression = (report.get("findings") or {}).get("compression")
    if compression:
        lines.append(f"        frames from a JPEG stream (quality ~{_figure(compression.get('quality'), 0)}): "
                     f"with its quantisation the bound is {_figure(compression.get('crlb_um'), 3)} um")
    if positive(noise.get("reference_resolution_um")):
        lines.append(f"        grating readout in steps of {_figure(noise['reference_resolution_um'], 3)} um: "
                     f"floor against it {_figure(noise['floor_um'], 3)} um")
    transients = report.get("findings", {}).get("transients")
    if transients and transients.get("count"):
        from graytrack.core.transients import summary_line

        lines.append(f"data    {summary_line(transients)}")
    return lines


def run(args: argparse.Namespace) -> int:
    from graytrack.core.diagnosis import diagnose
    from graytrack.core.recording import load
    from graytrack.service.progress import ProgressBar
    from graytrack.service.outputs import output_folder
    from graytrack.service.report import write_report

    output_folder(args.out)
    from graytrack.service.commands.calibrate import flip_for_calibration, mark_flip

    calibration = flip_for_calibration(load(args.recording), args.flip)
    validation = load(args.validate) if args.validate else None
    if validation is not None and args.flip:
        validation = validation.flipped()
    result = diagnose(calibration, validation, progress=ProgressBar("diagnose"))
    mark_flip(result.final_model, args.flip)
    paths = write_report(result, args.out)
    print("\n".join(summary_lines(result.report())))
    print(f"wrote   {', '.join(str(path) for path in paths.values())}")
    result.raise_if_refused()  # the report is written; the exit status says it is no success
    return 0
