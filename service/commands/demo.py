"""``graytrack demo``: the main job offline, on the virtual rig (what ``make run`` does for now).

Records the seed paper's rig, calibrates the ideal and the paper model, tracks a held-out run and
prints the error of each next to its bound (Cramér–Rao); then records a rig with effects the tools are
not told about and runs the closed loop on it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

DEFAULT_OUT = "out/demo"
UNDECLARED_EFFECTS = "gradient:per_10mm=0.05,prnu:sigma=0.015,flicker:mains_hz=60:depth=0.02"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("demo", help="offline end-to-end run on the virtual rig (no hardware)")
    parser.add_argument("--out", default=DEFAULT_OUT,
                        help=f"folder for recordings, models and the loop's report (default {DEFAULT_OUT}, created)")
    parser.add_argument("--seed", type=int, default=0)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from graytrack.core.recording import save
    from graytrack.core.seed_table import seed_table
    from graytrack.drivers.sim.scenarios import build_rig
    from graytrack.service.calibration_run import calibrate_recording, write_files
    from graytrack.service.outputs import output_folder

    if args.out == DEFAULT_OUT:  # the demo's own place, made on a fresh clone; a folder you name must exist
        Path(DEFAULT_OUT).mkdir(parents=True, exist_ok=True)
    out = output_folder(args.out)
    rig = build_rig("paper", seed=args.seed)
    cal, _ = rig.record(20.0)
    val, _ = rig.record(10.0)
    save(cal, out / "paper_cal.npz")
    save(val, out / "paper_val.npz")
    print(f"paper rig: {cal.n_frames} calibration + {val.n_frames} validation frames, {cal.n_pixels} px")
    print("  the seed paper's table, computed as the paper did (fit on the calibration sweep; the held-out sweep "
          "tracked from its first grating reading, error mean ± std against the grating):")
    for row in seed_table(cal, val):
        print("  " + row.line())
    print(f"closed loop on a rig with effects it is not told about ({UNDECLARED_EFFECTS}):")
    effects_rig = build_rig("paper", UNDECLARED_EFFECTS, seed=args.seed)
    recording, _ = effects_rig.record(20.0)
    save(recording, out / "effects_cal.npz")
    run_ = calibrate_recording(recording, "auto")
    paths = write_files(run_, out / "diagnosis")
    print("\n".join("  " + line for line in run_.lines()))
    print(f"report: {paths['html']}")
    return 0
