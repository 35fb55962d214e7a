"""A loop on its own daemon thread that stops on request: what the camera reader and the
grating poller both are, so the start/stop handshake lives in one place."""

from __future__ import annotations

import threading
from typing import TypeVar

WorkerT = TypeVar("WorkerT", bound="Worker")
JOIN_TIMEOUT_S = 5.0


class Worker:
    """Subclasses implement ``_run`` and poll ``self._stop`` (or wait on it) to end promptly."""

    def __init__(self, name: str) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        raise NotImplementedError

    def start(self: WorkerT) -> WorkerT:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=JOIN_TIMEOUT_S)
