"""``graytrack sim-controller --link PATH [--baud B]``: the simulated PI controller on a pseudo-terminal.

The same controller the daemon's virtual rig talks to (the rig's stage, its grating as ``POS?``),
served on a pty whose slave ``PATH`` links to, so that any serial client can open it as it would
open ``/dev/ttyUSB0``: PI's own PIPython or PIMikroMove under Wine, a lab's control system, a
terminal. SIGINT and SIGTERM stop it, remove the link and exit 0.
"""

from __future__ import annotations

import argparse
import os
import signal
import time
from pathlib import Path

from graytrack.service.errors import CliError

DEFAULT_BAUD = 115200
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
POLL_S = 0.1


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "sim-controller", help="serve the virtual rig's simulated PI GCS controller on a pseudo-terminal")
    parser.add_argument("--link", required=True,
                        help="path made a symlink to the pty (its folder must exist; an existing file is refused)")
    parser.add_argument("--baud", type=int, default=DEFAULT_BAUD,
                        help=f"baud rate clients are told to use (default {DEFAULT_BAUD}); "
                             "a pty carries bytes at any rate")
    parser.add_argument("--scenario", default="paper", help="the virtual rig's scenario (default paper, "
                                                            "the daemon's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.set_defaults(func=run)


def check_link(path: Path) -> None:
    """Refuse a path whose folder is missing, or one that holds anything but a link to a pty.

    A link into /dev/pts is what an earlier run that was killed outright leaves behind: replacing
    it is safe. Anything else (a real device, a file) is never replaced.
    """
    if not path.parent.is_dir():
        raise CliError(f"--link {path}: folder {path.parent} does not exist")
    if path.is_symlink():
        if not os.readlink(path).startswith("/dev/pts/"):
            raise CliError(f"--link {path}: already a link to {os.readlink(path)}, not to a pty; "
                           "remove it or choose another path")
    elif path.exists():
        raise CliError(f"--link {path}: already exists and is not a link; remove it or choose another path")


def run(args: argparse.Namespace) -> int:
    from graytrack.drivers.factory import virtual_rig_controller
    from graytrack.drivers.sim.scenarios import ScenarioError, build_rig

    if args.baud <= 0:
        raise CliError(f"--baud {args.baud}: must be a positive number of bits per second")
    link = Path(args.link).absolute()
    check_link(link)
    try:
        rig = build_rig(args.scenario, seed=args.seed)
    except ScenarioError as exc:
        raise CliError(str(exc)) from None
    _, controller = virtual_rig_controller(rig, path=str(link))
    received: list[int] = []
    # Python-level handlers, not sigwait: numpy's worker threads exist already and would take a
    # blocked-elsewhere SIGTERM with its default action (death, link left behind).
    previous = {sig: signal.signal(sig, lambda signum, frame: received.append(signum)) for sig in STOP_SIGNALS}
    try:
        controller.start()
        try:
            print(f"simulated PI controller on {os.readlink(link)}, linked at {link} ({args.baud} baud, "
                  f"scenario {args.scenario}); stop with Ctrl-C or SIGTERM", flush=True)
            while not received:  # handlers run between bytecodes of this thread: poll, do not block
                time.sleep(POLL_S)
        finally:
            controller.stop()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(f"stopped by {signal.Signals(received[0]).name}; {link} removed", flush=True)
    return 0
