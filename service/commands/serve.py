"""``graytrack serve [--config FILE] [--host H] [--port P] [--data-dir DIR]``: the daemon.

Without ``--config`` (or with ``kind = "sim"``) it runs the virtual rig behind the real drivers.
uvicorn handles SIGINT/SIGTERM by finishing requests and running the app's shutdown, which closes
the camera and the stage; after SIGTERM the exit status is 0.
"""

from __future__ import annotations

import argparse
import errno
import logging
import signal
import socket
import sys

from graytrack.service.errors import CliError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("serve", help="run the daemon: hardware (or the virtual rig), HTTP API, status page")
    parser.add_argument("--config", default=None, help="TOML file ([camera], [stage], [daemon], [sweep]); "
                                                       "default: the virtual rig")
    parser.add_argument("--host", default=None, help="address to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=None, help="TCP port (default 8000)")
    parser.add_argument("--data-dir", default=None, help="models, calibrations and the token "
                                                         "(default $STATE_DIRECTORY or ~/.local/state/graytrack)")
    parser.set_defaults(func=run)


def bind(host: str, port: int) -> socket.socket:
    """The listening socket, opened here so a bad address or a busy port is one line, not uvicorn's trace."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError, ValueError) as exc:
        raise CliError(f"--host {host!r}: not an address or name of this machine ({exc})") from None
    family, kind, proto, _, address = infos[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if family == socket.AF_INET6:
            sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
        sock.bind(address)
        sock.listen(128)
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise CliError(
                f"port {port} on {host} is already in use (another graytrack serve? choose --port)") from None
        raise CliError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    return sock


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from graytrack.drivers.config import ConfigError
    from graytrack.service.daemon.app import create_app
    from graytrack.service.daemon.errors import DataDirInUse, InsufficientStorage, UnsafeDataDir
    from graytrack.service.daemon.settings import load_settings

    try:
        settings = load_settings(args.config).with_overrides(host=args.host, port=args.port, data_dir=args.data_dir)
    except ConfigError as exc:
        raise CliError(str(exc)) from None
    if not 0 <= settings.daemon.port <= 65535:
        raise CliError(f"--port {settings.daemon.port}: must be 0..65535")
    daemon = settings.daemon
    from graytrack.service.blas import single_threaded_blas

    single_threaded_blas()  # the frame loop's small products on one core (service/blas.py)
    logging.basicConfig(level=daemon.log_level.upper(), stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        app = create_app(settings)
    except (DataDirInUse, UnsafeDataDir, InsufficientStorage) as exc:  # a full or read-only disk too: one line
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise CliError(f"data directory {settings.data_path()}: {exc.strerror or exc}") from None
    try:
        sock = bind(daemon.host, daemon.port)
    except CliError:
        app.state.storage.unlock()
        raise
    rig = "virtual rig" if settings.simulated else f"{settings.hardware.camera.kind} camera, GCS stage"
    port = sock.getsockname()[1]
    print(f"graytrack serve: {rig} at http://{daemon.host}:{port}  data {settings.data_path()}  "
          f"token from {app.state.token_source}", file=sys.stderr, flush=True)
    config = uvicorn.Config(app, log_level=daemon.log_level, access_log=daemon.log_level == "debug",
                            **app.state.server_options)
    server = uvicorn.Server(config)
    # uvicorn shuts down gracefully on SIGTERM and then re-raises it to the handler found at start;
    # a handler that only notes it turns "killed by SIGTERM" into the clean exit status 0 that
    # systemd and scripts expect after the hardware has been closed.
    terminated: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, frame: terminated.append(signum))
    server.run(sockets=[sock])
    if terminated:
        print("graytrack serve: stopped (SIGTERM), hardware closed", file=sys.stderr, flush=True)
    return 0 if server.started else 1
