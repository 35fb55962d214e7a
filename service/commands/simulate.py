"""``graytrack simulate --scenario NAME [--seconds S] [--effects a,b] [--seed N] [--truth FILE] --out REC.npz``.

Records from the virtual rig (graytrack.drivers.sim). ``--list`` names the scenarios and the
effects with their parameters. Ground truth goes to ``--truth`` only, never into the recording.
"""

from __future__ import annotations

import argparse
import math

from graytrack.service.errors import CliError

EFFECT_SYNTAX = (
    "Effects: --effects NAME[:KEY=VALUE[:KEY=VALUE...]][,NAME...]; repeat --effects to add more.\n"
    "A bare KEY=VALUE after a comma belongs to the previous effect (flicker:mains_hz=60,depth=0.05)."
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "simulate", help="record from the virtual rig",
        description="Record from the virtual rig. " + EFFECT_SYNTAX,
    )
    parser.add_argument("--list", action="store_true", help="list scenarios and effects (with parameters) and exit")
    parser.add_argument("--scenario", default="paper", help="scenario name (default: paper)")
    parser.add_argument("--seconds", type=float, default=None, help="recording length (default: the scenario's)")
    parser.add_argument("--effects", action="append", default=[], metavar="SPEC",
                        help="effects to switch on, e.g. tilt:deg=0.5,flicker")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0): same seed, same recording")
    parser.add_argument("--run", type=int, default=0, metavar="N",
                        help="another session of the same rig (same seed): same fixed patterns, noise of its own")
    parser.add_argument("--truth", default=None, metavar="FILE", help="also write the ground truth (.npz) here")
    parser.add_argument("--out", default=None, metavar="REC.npz", help="recording to write")
    parser.set_defaults(func=run)


def listing() -> str:
    from graytrack.drivers.sim.scenarios import list_effects, list_scenarios

    lines = ["Scenarios:"]
    lines += [f"  {name:<12} {doc}" for name, doc in list_scenarios().items()]
    lines.append("")
    lines.append(EFFECT_SYNTAX)
    lines += [f"  {name:<18} {doc}" for name, doc in list_effects().items()]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from graytrack.core.recording import describe_bytes, memory_budget_bytes, save, working_bytes
    from graytrack.drivers.sim.scenarios import build_rig
    from graytrack.service.outputs import output_file
    from graytrack.service.progress import ProgressBar

    if args.list:
        print(listing())
        return 0
    if not args.out:
        raise CliError("--out REC.npz is required (or --list)")
    if args.seconds is not None and not (math.isfinite(args.seconds) and args.seconds > 0):
        raise CliError(f"--seconds must be positive and finite, got {args.seconds:g}")
    output_file(args.out)
    output_file(args.out if args.out.endswith(".npz") else args.out + ".npz")  # the name save() writes
    if args.truth:
        output_file(args.truth, "--truth")
    try:
        rig = build_rig(args.scenario, args.effects, seed=args.seed, run=args.run)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    seconds = rig.config.default_seconds if args.seconds is None else args.seconds
    frames = math.ceil(seconds * rig.frame_rate_hz)
    need, budget = working_bytes((frames, rig.n_rows, rig.n_pixels)), memory_budget_bytes()
    if need > budget:
        longest = budget / (8 * rig.n_rows * rig.n_pixels * rig.frame_rate_hz)
        raise CliError(f"--seconds {seconds:g}: {frames} frames of {rig.n_rows}x{rig.n_pixels} px need "
                       f"{describe_bytes(need)}, beyond the memory budget of {describe_bytes(budget)}; "
                       f"at most {longest:.0f} s for this scenario")
    rec, truth = rig.record(args.seconds, progress=ProgressBar("simulate"))
    path = save(rec, args.out)
    shape = "×".join(str(s) for s in rec.frames.shape)
    print(f"wrote   {path}: {shape} {rec.frames.dtype} frames, {rec.t[-1] - rec.t[0]:.3f} s, scenario {args.scenario}"
          + (f", effects {', '.join(rig.config.effects)}" if rig.config.effects else ""))
    if args.truth:
        print(f"wrote   {truth.save(args.truth)} (ground truth)")
    return 0
