"""Where the client's bearer token comes from: given, or the daemon's ``DATA/token``."""

from __future__ import annotations

import os
from pathlib import Path

from graytrack.client.errors import GraytrackClientError


def resolve_token(token: str | None, data_dir: str | os.PathLike[str] | None) -> str | None:
    """``token`` if given, else the content of ``data_dir/token`` (the file the daemon writes at first start);
    ``~`` in ``data_dir`` is the home directory, as in the daemon's default ``~/.local/state/graytrack``."""
    if token is not None:
        token = token.strip()
        if not token:
            raise ValueError("token is empty: pass the daemon's token, or data_dir=")
        return token
    if data_dir is None:
        return None
    path = Path(data_dir).expanduser() / "token"
    try:
        text = path.read_text(encoding="utf-8").strip()
    except FileNotFoundError:
        raise GraytrackClientError(f"{path}: no token file (the daemon writes it at its first start)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise GraytrackClientError(f"{path}: cannot read the token: {exc}") from None
    if not text:
        raise GraytrackClientError(f"{path}: the token file is empty")
    return text
