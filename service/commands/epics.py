"""``graytrack epics --url URL --prefix P [--rate HZ] [--data-dir DIR | --token-file FILE]``: the daemon as
EPICS Channel Access PVs (``graytrack.service.epics_bridge``).

caproto is an extra (``graytrack[epics]``): it is imported here, when the command runs, so that
graytrack without it still starts, and its absence is one line naming the install. Ports and
interfaces are Channel Access's own environment (``EPICS_CAS_SERVER_PORT``, ``EPICS_CAS_INTF_ADDR_LIST``…).
SIGTERM and SIGINT stop the server; the exit status is then 0.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from pathlib import Path

from graytrack.service.errors import CliError

MISSING = "caproto is not installed: pip install 'graytrack[epics]'"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("epics", help="serve the daemon's position, state, calibration and moves as "
                                                 "EPICS Channel Access PVs (needs graytrack[epics])")
    parser.add_argument("--url", required=True, help="the daemon, e.g. http://127.0.0.1:8000")
    parser.add_argument("--prefix", required=True, help="PV prefix: LAB:GT1 serves LAB:GT1:X_MM, LAB:GT1:STATE…")
    parser.add_argument("--rate", type=float, default=10.0, help="position PV updates per second (default 10)")
    token = parser.add_mutually_exclusive_group()
    token.add_argument("--data-dir", default=None, help="the daemon's data directory (its token file, for the "
                                                        "CALIBRATE and TARGET_MM writes)")
    token.add_argument("--token-file", default=None, help="a file holding the daemon's token")
    parser.set_defaults(func=run)


def read_token_file(path: str) -> str:
    text = Path(path).read_text(encoding="utf-8").strip()
    if not text:
        raise CliError(f"{path}: the token file is empty")
    return text


class RefusalsInOneLine(logging.Filter):
    """caproto logs a refused write with its traceback; a refusal by the daemon is one line (the
    client got the same sentence as its write error)."""

    def __init__(self, refusals: tuple[type[BaseException], ...]) -> None:
        super().__init__()
        self.refusals = refusals

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, self.refusals):
            record.msg, record.args, record.exc_info = "write refused: %s", (exc,), None
        return True


def run(args: argparse.Namespace) -> int:
    try:
        import caproto  # noqa: F401  (the extra; the bridge imports it too)
    except ImportError:
        raise CliError(MISSING) from None
    from caproto.asyncio.server import start_server

    from graytrack.client import AsyncClient, GraytrackClientError
    from graytrack.service.epics_bridge import TrackerPVs, pv_prefix

    try:
        prefix = pv_prefix(args.prefix)
        token = read_token_file(args.token_file) if args.token_file else None
        client = AsyncClient(args.url, token=token, data_dir=args.data_dir)
        group = TrackerPVs(prefix=prefix, client=client, rate_hz=args.rate)
    except (ValueError, GraytrackClientError) as exc:
        raise CliError(str(exc)) from None

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("graytrack epics: %(message)s"))
    handler.addFilter(RefusalsInOneLine((GraytrackClientError, ValueError)))
    for name, level in (("graytrack.epics", logging.INFO), ("caproto", logging.WARNING)):
        logger = logging.getLogger(name)
        logger.addHandler(handler)
        logger.setLevel(level)
        logger.propagate = False
    log = logging.getLogger("graytrack.epics")
    log.info("serving %d PVs %s{%s} for %s at %g Hz", len(group.pvdb), prefix,
             ",".join(name[len(prefix):] for name in group.pvdb), client.url, args.rate)

    async def serve() -> None:
        server = asyncio.ensure_future(start_server(group.pvdb))
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, server.cancel)
        try:
            await server
        except asyncio.CancelledError:
            pass
        finally:
            await client.aclose()

    asyncio.run(serve())
    return 0
