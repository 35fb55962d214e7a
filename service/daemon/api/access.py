"""``GET /api/access``: where the bearer token is, so the page can name the file instead of "DATA/token".

A newcomer on the status page needs the token before any control works; the daemon knows its data
directory and where its token came from, the page does not. Paths only, never the token: reads are
open, and whoever can read the file is whoever may act.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request

from graytrack.wire import Access

router = APIRouter(tags=["status"])


@router.get("/api/access", response_model=Access)
def access(request: Request) -> Any:
    """Where the token comes from (``file`` with its path, or ``config``) and the data directory."""
    source = request.app.state.token_source  # "config", or the token file's path (app.resolve_token)
    from_config = source == "config"
    return {"token_from": "config" if from_config else "file",
            "token_file": None if from_config else str(Path(source).absolute()),
            "data_dir": str(Path(request.app.state.storage.root).absolute())}
