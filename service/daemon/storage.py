"""The daemon's data directory: the current model, the bearer token and every calibration run.

Layout::

    DATA/token                      bearer token, mode 0600, generated at first start
    DATA/model.json                 the model the daemon tracks with (loaded at start)
    DATA/calibrations/<id>/         one sweep: status.json, recording.npz, model.json, report.json(, report.html)

Everything is written atomically (temporary file + rename), so a crash or a full disk never leaves
a half-written model that would be loaded at the next start. Calibration ids sort by time, which
is what "latest" means.
"""

from __future__ import annotations

import json
import logging
import os
import re
import secrets
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from graytrack.core.errors import GraytrackError
from graytrack.core.files import write_atomic
from graytrack.core.models import load_model, save_model
from graytrack.core.models.fourier import FourierModel

log = logging.getLogger("graytrack.daemon")
CALIBRATION_ID = re.compile(r"^\d{8}T\d{6}\d{6}Z$")


class Storage:
    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True, mode=0o700)  # holds the token
        self.calibrations = self.root / "calibrations"
        self.calibrations.mkdir(exist_ok=True)
        self._last_time: datetime | None = None

    # -- token -----------------------------------------------------------------------------
    @property
    def token_path(self) -> Path:
        return self.root / "token"

    def token(self) -> tuple[str, bool]:
        """The stored token, created (mode 0600, never readable by others) if missing; ``(token, created)``."""
        try:
            fd = os.open(self.token_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            token = self.token_path.read_text().strip()
            if len(token) < 16:
                raise GraytrackError(f"{self.token_path}: token shorter than 16 characters; delete it to regenerate")
            return token, False
        token = secrets.token_urlsafe(32)
        with os.fdopen(fd, "w") as fh:
            fh.write(token + "\n")
        return token, True

    # -- current model ---------------------------------------------------------------------
    @property
    def model_path(self) -> Path:
        return self.root / "model.json"

    def load_current_model(self) -> FourierModel | None:
        """The saved model, or None when there is none (an unreadable one is logged, not fatal)."""
        if not self.model_path.exists():
            return None
        try:
            return load_model(self.model_path)
        except GraytrackError as exc:
            log.error("ignoring the saved model: %s", exc)
            return None

    def save_current_model(self, model: FourierModel) -> Path:
        return save_model(model, self.model_path)

    # -- calibrations ----------------------------------------------------------------------
    def new_calibration_id(self) -> str:
        """Time-ordered and unique within this process (two requests in one microsecond still differ)."""
        now = datetime.now(timezone.utc)
        if self._last_time is not None and now <= self._last_time:
            now = self._last_time + timedelta(microseconds=1)
        self._last_time = now
        return now.strftime("%Y%m%dT%H%M%S%fZ")

    def calibration_dir(self, calibration_id: str) -> Path:
        if not CALIBRATION_ID.match(calibration_id):
            raise KeyError(calibration_id)
        return self.calibrations / calibration_id

    def write_status(self, calibration_id: str, document: dict[str, Any]) -> None:
        write_atomic(self.calibration_dir(calibration_id) / "status.json", json.dumps(document, indent=1, default=float))

    def read_status(self, calibration_id: str) -> dict[str, Any] | None:
        try:
            path = self.calibration_dir(calibration_id) / "status.json"
        except KeyError:
            return None
        try:
            return json.loads(path.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None

    def latest_calibration_id(self) -> str | None:
        ids = sorted(p.name for p in self.calibrations.iterdir() if CALIBRATION_ID.match(p.name))
        return ids[-1] if ids else None
