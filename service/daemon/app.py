"""The daemon's HTTP interface (DESIGN.md, "the daemon's interface") as a FastAPI app.

Reads are open; every request that changes state (calibrate, move, stop) needs
``Authorization: Bearer <token>``. Errors are always JSON ``{"error": "one clear sentence"}``
with a 4xx/5xx status, never an HTML page or a traceback. The rig's threads do the work; the
handlers only ask and report, so a slow camera never blocks the event loop.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any, AsyncIterator

from fastapi import Depends, FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field
from starlette.exceptions import HTTPException

import graytrack.web
from graytrack.service.daemon import metrics
from graytrack.service.daemon.broadcast import Broadcaster
from graytrack.service.daemon.rig import HardwareFactory, Rig, RigError, default_factory
from graytrack.service.daemon.settings import Settings
from graytrack.service.daemon.storage import Storage

log = logging.getLogger("graytrack.daemon")
WEB_DIR = Path(graytrack.web.__file__).parent


class MoveRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    target_mm: float = Field(allow_inf_nan=False, description="absolute target within the soft limits")


def resolve_token(settings: Settings, storage: Storage) -> tuple[str, str]:
    """The bearer token and where it comes from ("config", or the token file's path)."""
    if settings.daemon.token:
        return settings.daemon.token, "config"
    token, created = storage.token()
    if created:
        log.info("generated a bearer token in %s (mode 0600)", storage.token_path)
    return token, str(storage.token_path)


def _error(status: int, message: str, **extra: Any) -> JSONResponse:
    headers = {"WWW-Authenticate": "Bearer"} if status == 401 else None
    return JSONResponse({"error": message, **extra}, status_code=status, headers=headers)


def _describe_validation(errors: list[dict[str, Any]]) -> str:
    first = errors[0] if errors else {}
    if first.get("type") == "json_invalid":
        return "request body is not valid JSON"
    where = ".".join(str(part) for part in first.get("loc", ()) if part != "body") or "body"
    return f"invalid request: {where}: {first.get('msg', 'invalid')}"


def create_app(settings: Settings, factory: HardwareFactory = default_factory) -> FastAPI:
    storage = Storage(settings.data_path())
    token, token_source = resolve_token(settings, storage)
    broadcaster = Broadcaster()
    rig = Rig(settings, storage, broadcaster.publish, factory)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        broadcaster.bind(asyncio.get_running_loop())
        rig.start()
        try:
            yield
        finally:
            await asyncio.to_thread(rig.close)

    app = FastAPI(title="graytrack", lifespan=lifespan, docs_url="/api/docs", redoc_url=None,
                  openapi_url="/api/openapi.json")
    app.state.rig, app.state.storage, app.state.broadcaster = rig, storage, broadcaster
    app.state.token_source = token_source

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> JSONResponse:
        return _error(exc.status_code, str(exc.detail))

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [{k: v for k, v in e.items() if k in ("type", "loc", "msg")} for e in exc.errors()]
        return _error(422, _describe_validation(errors), detail=errors)

    @app.exception_handler(RigError)
    async def rig_error(request: Request, exc: RigError) -> JSONResponse:
        return _error(exc.status, str(exc))

    def require_token(request: Request) -> None:
        header = request.headers.get("authorization", "")
        scheme, _, given = header.partition(" ")
        if scheme.lower() != "bearer" or not given:
            raise HTTPException(401, "missing bearer token: send 'Authorization: Bearer <token>'")
        if not hmac.compare_digest(given.strip().encode(), token.encode()):
            raise HTTPException(401, "invalid bearer token")

    authorized = [Depends(require_token)]

    @app.get("/healthz")
    def healthz() -> dict[str, Any]:
        """Liveness: the process answers. The rig's own health is ``state`` (a fault is not death)."""
        return {"ok": True, "state": rig.state}

    @app.get("/api/status")
    def status() -> dict[str, Any]:
        return rig.status()

    @app.post("/api/calibration", status_code=202, dependencies=authorized)
    def start_calibration() -> dict[str, Any]:
        job = rig.start_calibration()
        return {**job.to_dict(), "url": f"/api/calibration/{job.id}"}

    @app.get("/api/calibration/latest")
    def latest_calibration() -> dict[str, Any]:
        document = rig.latest_calibration()
        if document is None:
            raise HTTPException(404, "no calibration has been run yet")
        return document

    @app.get("/api/calibration/{calibration_id}")
    def calibration(calibration_id: str) -> dict[str, Any]:
        document = rig.calibration(calibration_id)
        if document is None:
            raise HTTPException(404, f"no calibration {calibration_id!r}")
        return document

    @app.post("/api/stage/move", status_code=202, dependencies=authorized)
    def move(request: MoveRequest) -> dict[str, Any]:
        return rig.move(request.target_mm)

    @app.post("/api/stage/stop", dependencies=authorized)
    def stop() -> dict[str, Any]:
        return rig.stop()

    @app.get("/metrics")
    def prometheus() -> PlainTextResponse:
        return PlainTextResponse(metrics.render(rig, broadcaster), media_type=metrics.CONTENT_TYPE)

    @app.websocket("/ws/position")
    async def positions(websocket: WebSocket) -> None:
        await websocket.accept()
        queue = broadcaster.subscribe()
        closed = asyncio.create_task(_until_closed(websocket))
        try:
            while True:
                getter = asyncio.create_task(queue.get())
                done, _ = await asyncio.wait({getter, closed}, return_when=asyncio.FIRST_COMPLETED)
                if getter not in done:
                    getter.cancel()
                    return
                await websocket.send_text(getter.result())
                broadcaster.sent += 1
        except (WebSocketDisconnect, RuntimeError):
            return
        finally:
            broadcaster.unsubscribe(queue)
            closed.cancel()

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(WEB_DIR / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=WEB_DIR), name="static")
    return app


async def _until_closed(websocket: WebSocket) -> None:
    """Returns when the client goes away (clients have nothing to say on this socket)."""
    while True:
        message = await websocket.receive()
        if message["type"] == "websocket.disconnect":
            return
