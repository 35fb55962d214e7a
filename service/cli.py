"""``graytrack`` command line (docs/contracts.md, "command line").

Every subcommand lives in ``graytrack.service.commands.<name>`` and registers itself; this module
only dispatches and turns expected failures into a one-line reason with exit status 2, so that bad
input never ends in a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from graytrack import __version__

# Order here is the order in `graytrack --help`.
COMMAND_MODULES = ("simulate", "calibrate", "track", "diagnose", "batch", "history", "serve", "demo", "sim_controller",
                   "epics")

EXIT_BAD_INPUT = 2
# `pip install graytrack` is the client alone; a command that needs the numerical stack says how to get it
DAEMON_EXTRA = "pip install 'graytrack[daemon]'"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand; with ``command`` (one of :data:`COMMAND_MODULES`) only that
    one's is registered: its arguments, usage, help and errors are the same, and a run of one
    command (a ``track`` of a short recording) does not pay for building all the others'."""
    parser = argparse.ArgumentParser(
        prog="graytrack",
        description="Camera + printed sine target as a displacement sensor: "
                    "simulate, calibrate, track, diagnose, serve.",
    )
    parser.add_argument("--version", action="version", version=f"graytrack {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    alone = command in COMMAND_MODULES
    for name in (command,) if alone else COMMAND_MODULES:
        importlib.import_module(f"graytrack.service.commands.{name}").register(subparsers)
    if alone and command not in subparsers.choices:  # a module whose command is spelt otherwise: all of them
        return build_parser()
    return parser


def expected_errors() -> tuple[type[BaseException], ...]:
    """Failures that mean bad input or a refused computation, not a bug."""
    from graytrack.core.errors import GraytrackError
    from graytrack.service.errors import CliError

    return (CliError, GraytrackError, OSError)


def reason(exc: BaseException) -> str:
    """The one line shown for an expected failure; an OS error names its file, not its errno."""
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.filename}: {exc.strerror}" if exc.filename else exc.strerror
    text = str(exc)
    return text.splitlines()[0] if text else type(exc).__name__


def missing_extra(exc: ModuleNotFoundError, command: str | None) -> int:
    """A third-party module absent (a client-only install): one line naming it and the extra, no traceback."""
    if exc.name is None or exc.name.split(".")[0] == "graytrack":
        raise exc  # graytrack's own module missing is a broken install, not a missing extra
    print(f"graytrack{' ' + command if command else ''}: error: {exc.name} is not installed; "
          f"the daemon and the commands need the numerical stack: {DAEMON_EXTRA}", file=sys.stderr)
    return EXIT_BAD_INPUT


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    # the command named first (the usual call) needs only its own parser; anything else (--help,
    # --version, a typo) gets them all
    command = argv[0] if argv and argv[0] in COMMAND_MODULES else None
    try:
        parser = build_parser(command)
    except ModuleNotFoundError as exc:
        return missing_extra(exc, command)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ModuleNotFoundError as exc:
        return missing_extra(exc, args.command)
    except expected_errors() as exc:
        print(f"graytrack {args.command}: error: {reason(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"graytrack {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
