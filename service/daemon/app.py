"""The daemon's HTTP interface (docs/contracts.md, "the daemon's interface") as a FastAPI app.

Reads are open on loopback (beyond it they need the token too, `[daemon] read_token`, :mod:`api.read_policy`);
every request that changes state needs ``Authorization: Bearer <token>``,
checked before its body is read (:mod:`api.security`). Errors are always JSON
``{"error": "one clear sentence"}``: every refusal is a :class:`DaemonError` whose ``status`` is
the answer, mapped here in one place. The rig's threads do the work; the handlers only ask and
report, so a slow camera never blocks the event loop.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import sys
from contextlib import asynccontextmanager
from typing import Any, AsyncIterator

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException

from graytrack.service.daemon.api import access, calibration, history, maps, pages, profile, stage, status, stream, trim
from graytrack.service.daemon.api.pages import WEB_DIR
from graytrack.service.daemon.api.schema import strict_openapi
from graytrack.service.daemon.api.security import WebGuard, WebPolicy
from graytrack.service.daemon.broadcast import Broadcaster
from graytrack.service.daemon.errors import DaemonError
from graytrack.service.daemon.limits import ConnectionLimits, ServingCpu, server_protocols
from graytrack.service.daemon.logs import LogGuard
from graytrack.service.heap import freeze_long_lived, thaw, warm_tracking
from graytrack.service.daemon.datadir import require_room
from graytrack.service.daemon.history import open_history
from graytrack.drivers.realtime import pin_process, raise_thread_priority, restore_process
from graytrack.service.daemon.rig import HardwareFactory, Rig, default_factory
from graytrack.service.daemon.settings import Settings
from graytrack.service.daemon.startup import WarmUp
from graytrack.service.daemon.storage import Storage
from graytrack.service.daemon.ws_protocol import StreamProtocol

log = logging.getLogger("graytrack.daemon")
ROUTERS = (status.router, calibration.router, history.router, profile.router, maps.router, stage.router, stream.router,
           pages.router, trim.router, access.router)
# The frame thread and the event loop share the GIL. A thread that computes for long (a calibration
# fit, a status document) holds it for Python's default 5 ms switch interval before the stream's
# thread gets a turn: five frames at 1 kHz. 0.1 ms bounds that wait to a tenth of a frame (against
# 0.5 ms, the 16-row closed-loop stream's p99 at 1 kHz × 4 clients was lower in each of four
# interleaved pairs of runs of bench/stream_latency.py, median 7.4 against 10.7 ms over 12 runs each).
SWITCH_INTERVAL_S = 0.0001


def server_options(settings: Settings, limits: ConnectionLimits) -> dict[str, Any]:
    """How uvicorn serves this app (``graytrack serve`` and the tests use the same). No permessage-deflate
    unless configured: the stream encodes each message once for all clients, and deflate would compress it
    again per client on the event loop (~100 us a message; at 1 kHz x 4 clients that was the loop's largest
    cost and the stream's latency tail) to save bytes on ~300-byte messages that pages receive decimated.
    The protocol is uvicorn's websockets-sansio one that also takes pre-framed messages (ws_protocol.py):
    without deflate, each message is framed once and the same bytes are written to every client. Both
    protocols enforce ``limits`` (limits.py: connections, request time, head and frame sizes)."""
    return {**server_protocols(limits, StreamProtocol), "ws_per_message_deflate": settings.daemon.ws_compression,
            "lifespan": "on"}


def resolve_token(settings: Settings, storage: Storage) -> tuple[str, str]:
    """The bearer token and where it comes from ("config", or the token file's path)."""
    if settings.daemon.token:
        return settings.daemon.token, "config"
    token, created = storage.token()
    if created:
        log.info("generated a bearer token in %s (mode 0600)", storage.token_path)
    return token, str(storage.token_path)


def _error(status: int, message: str, headers: dict[str, str] | None = None, **extra: Any) -> JSONResponse:
    headers = {**(headers or {}), **({"WWW-Authenticate": "Bearer"} if status == 401 else {})}
    return JSONResponse({"error": message, **extra}, status_code=status, headers=headers or None)


def _unreadable_body(exc: HTTPException) -> str | None:
    """Why a JSON body could not be read, when FastAPI's 400 came from decoding it (bytes that are not
    UTF-8, nesting beyond the parser's depth, an integer beyond Python's digit limit): the contract
    answers every body it cannot take with 422, as it does for malformed JSON."""
    cause = exc.__cause__
    if exc.status_code != 400:
        return None
    if isinstance(cause, UnicodeDecodeError):
        return f"request body is not valid JSON: not UTF-8 (byte {cause.object[cause.start]:#04x} at {cause.start})"
    if isinstance(cause, RecursionError):
        return "request body is not valid JSON for this daemon: nested too deeply"
    if isinstance(cause, ValueError) and "digits" in str(cause):
        return f"request body is not valid JSON for this daemon: an integer over {sys.get_int_max_str_digits()} digits"
    if isinstance(cause, ValueError):
        return f"request body is not valid JSON for this daemon: {cause}"
    return None


def _describe_validation(errors: list[dict[str, Any]]) -> str:
    first = errors[0] if errors else {}
    if first.get("type") == "json_invalid":
        return "request body is not valid JSON"
    where = ".".join(str(part) for part in first.get("loc", ()) if part != "body") or "body"
    return f"invalid request: {where}: {first.get('msg', 'invalid')}"


def create_app(settings: Settings, factory: HardwareFactory = default_factory) -> FastAPI:
    """The app on ``settings``; holds the data directory's lock from here until its shutdown."""
    storage = Storage(settings.data_path())
    require_room(storage.root)  # a full or read-only disk: refused before anything is locked, opened or renamed
    storage.lock()
    try:
        token, token_source = resolve_token(settings, storage)
    except BaseException:
        storage.unlock()
        raise
    broadcaster = Broadcaster()
    try:
        history, rebuilt = open_history(storage.root / "record.sqlite")
    except BaseException:
        storage.unlock()
        raise
    rig = Rig(settings, storage, history, broadcaster.publish, factory)
    startup = WarmUp(functools.partial(warm_tracking, (settings.daemon.engine,)), settings.daemon.realtime_priority)
    if rebuilt is not None:
        log.error("%s", rebuilt)
        rig.event("record_rebuilt", rebuilt)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        broadcaster.bind(asyncio.get_running_loop())
        previous = sys.getswitchinterval()
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        pinned_from = pin_process(settings.daemon.cpu_cores)  # before the rig's threads and process start
        # before the rig's threads: they start normal
        raise_thread_priority(settings.daemon.realtime_priority, "event loop")

        def open_rig() -> None:  # on the event loop, once tracking is warm (service/daemon/startup.py)
            rig.start()
            freeze_long_lived()  # full collections walk what the frames leave, not the daemon (service/heap.py)

        logs = LogGuard(token)  # uvicorn's loggers are configured by now: the token kept out of every line
        logs.install()
        flushing = asyncio.create_task(logs.flush_every())
        opening = asyncio.create_task(startup.run(open_rig))  # what tracking loads on first use, before the freeze
        try:
            yield
        finally:
            opening.cancel()  # stopped while warming up: the rig never opens
            flushing.cancel()
            await asyncio.to_thread(rig.close)
            thaw()
            sys.setswitchinterval(previous)
            restore_process(pinned_from)
            history.close()
            storage.unlock()
            logs.close()

    docs = settings.daemon.api_docs
    app = FastAPI(title="graytrack", lifespan=lifespan, docs_url="/api/docs" if docs else None, redoc_url=None,
                  openapi_url="/api/openapi.json",
                  description="Camera displacement sensor daemon. State changes need a bearer token.")
    app.state.rig, app.state.storage, app.state.broadcaster = rig, storage, broadcaster
    app.state.startup = startup
    app.state.token_source = token_source
    # what serving costs, the stream's deliveries apart: the stream is the rig's output, a request is not
    serving = ServingCpu()
    app.state.limits = ConnectionLimits(settings.daemon, serving_cpu=lambda: serving() - broadcaster.cpu_s,
                                        rig_lost=rig.frames_lost)
    app.state.server_options = server_options(settings, app.state.limits)
    app.state.policy = WebPolicy(settings.daemon, token)
    app.add_middleware(WebGuard, policy=app.state.policy)
    app.openapi = strict_openapi(app, settings)  # type: ignore[method-assign]  # the rig's limits filled in

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> JSONResponse:
        unreadable = _unreadable_body(exc)
        if unreadable is not None:
            return _error(422, unreadable)
        headers = dict(exc.headers or {})
        allowed = [method.strip() for method in headers.get("Allow", "").split(",") if method.strip()]
        if "GET" in allowed and "HEAD" not in allowed:  # every GET route answers HEAD too (api/security.py)
            headers["Allow"] = ", ".join([*allowed, "HEAD"])
        return _error(exc.status_code, str(exc.detail), headers=headers or None)  # a 405's Allow among them

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [{k: v for k, v in e.items() if k in ("type", "loc", "msg")} for e in exc.errors()]
        message = _describe_validation(errors)
        declared = request.headers.get("content-type", "")
        if request.method in ("POST", "PUT", "PATCH") and not declared.startswith("application/json") \
                and any(e.get("loc", ("",))[0] == "body" for e in errors):
            # curl -d without -H sends application/x-www-form-urlencoded: the body was never read as JSON
            message = (f"the body must be JSON sent with the header Content-Type: application/json "
                       f"(got {declared or 'no Content-Type'}); {message}")
        return _error(422, message, detail=errors)

    @app.exception_handler(DaemonError)
    async def daemon_error(request: Request, exc: DaemonError) -> JSONResponse:
        return _error(exc.status, str(exc))

    for router in ROUTERS:
        app.include_router(router)
    app.mount("/static", StaticFiles(directory=WEB_DIR), name="static")
    return app
