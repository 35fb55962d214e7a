"""The print texture the daemon learned, kept as part of the model of record (``DATA/texture.json``).

Why kept: a mark learned on the print (dust settled on it: core/texture.py) is part of what every
later position rests on, as much as the model's coefficients. A daemon restarted on the same model
would otherwise set those samples aside again, lose frames until it had relearnt each mark, and
say nothing of why. So what the live tracker learned is written beside the model, tied to the
calibration it was learned for (its id and the SHA-256 of ``DATA/model.json``), reloaded into the
tracker at start for that calibration only, and removed by the same switch that installs another
model (a new calibration, a rollback: :meth:`Storage.switch_model`), since marks learned against
one model's print map sit elsewhere on another's.

Who does what: the frame loop takes a :class:`TextureSnapshot` when the marks change
(:class:`TextureSnapshotter`: an event, or every ``REFRESH_FRAMES`` frames while marks are refined),
never touching the disk; the rig's watchdog hands the newest to :meth:`TextureStore.save`, which
writes it atomically at most every ``SAVE_EVERY_S`` (the first change at once). A full or read-only
disk is the ``storage`` fault (:mod:`datadir`), the state stays in memory and the write is tried
again: the daemon keeps tracking with what it learned. The model switch runs under the store's
lock (:meth:`TextureStore.switch`), so a save never writes the old model's marks after it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, TypeVar

from graytrack.core.files import write_atomic
from graytrack.core.texture import Texture
from graytrack.service.daemon.datadir import DataDirHealth
from graytrack.service.daemon.storage import Storage
from graytrack.service.daemon.worker import describe

log = logging.getLogger("graytrack.daemon")
T = TypeVar("T")
SAVE_EVERY_S = 10.0  # at most one write in this long (the rig's clock): marks learned in a burst cost one write
REFRESH_FRAMES = 500  # frames between two snapshots while learned marks are refined without an event
NEWEST = 3  # marks the status shows (the newest learned)
SHOWN = ("x_mm", "from_mm", "to_mm", "depth", "depth_sigma", "frames", "learned_at")  # of each, what status shows


@dataclass(frozen=True)
class TextureSnapshot:
    """What a tracker had learned at one frame, for the calibration ``calibration`` (None: a model
    placed by hand)."""

    calibration: str | None
    state: dict[str, Any]  # Texture.state(): the document kept on disk


class TextureSnapshotter:
    """On the frame loop: ``observe`` after each tracked frame; ``latest`` is the newest snapshot."""

    def __init__(self) -> None:
        self.latest: TextureSnapshot | None = None
        self._texture: Texture | None = None
        self._events = 0
        self._frames = 0

    def observe(self, texture: Texture | None, calibration: str | None) -> None:
        if texture is None:
            self._texture, self.latest = None, None
            return
        self._frames += 1
        changed = texture is not self._texture or len(texture.events) != self._events
        if not changed and self._frames >= REFRESH_FRAMES and not texture.learned:
            self._frames = 0  # nothing to refine: looked at again in REFRESH_FRAMES
        if not (changed or self._frames >= REFRESH_FRAMES):
            return
        self._texture, self._events, self._frames = texture, len(texture.events), 0
        self.latest = TextureSnapshot(calibration, texture.state())


def model_digest(storage: Storage) -> str | None:
    """SHA-256 of ``DATA/model.json`` (None: there is none)."""
    try:
        return hashlib.sha256(storage.model_path.read_bytes()).hexdigest()
    except FileNotFoundError:
        return None


class TextureStore:
    def __init__(self, storage: Storage, health: DataDirHealth, clock: Callable[[], float],
                 on_event: Callable[[str, str], None]) -> None:
        self.storage, self.health, self.clock, self.on_event = storage, health, clock, on_event
        self.lock = threading.Lock()  # held by a save and by the model switch (``switch``)
        self._written: TextureSnapshot | None = None  # the snapshot on disk (None: none of this run)
        self._last_try = -math.inf
        self._restored: tuple[str | None, int] = (None, 0)  # (calibration, marks) restored at start
        self._newest: TextureSnapshot | None = None  # the newest snapshot handed to save

    def newest(self, calibration: str | None) -> dict[str, Any] | None:
        """The newest state learned for ``calibration`` (a frame loop restarted goes on from it)."""
        newest = self._newest or self._written
        return newest.state if newest is not None and newest.calibration == calibration else None

    @property
    def path(self):
        return self.storage.texture_path

    # -- at start ----------------------------------------------------------------------------
    def load(self, calibration: str | None) -> dict[str, Any] | None:
        """The texture state saved for ``calibration`` (the active one, whose model is in ``DATA/model.json``),
        or None: none saved, or saved for another model (said, and left for the next save to replace)."""
        try:
            document = json.loads(self.path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError, RecursionError) as exc:
            self.on_event("texture_ignored", f"{self.path.name} cannot be read ({describe(exc)}): the marks learned on "
                                             f"the print before this start are not restored")
            return None
        if not isinstance(document, dict) or not isinstance(document.get("texture"), dict):
            self.on_event("texture_ignored", f"{self.path.name} is not a texture this daemon wrote: not restored")
            return None
        if document.get("calibration") != calibration or document.get("model_sha256") != model_digest(self.storage):
            self.on_event("texture_ignored", f"{self.path.name} holds marks learned for calibration "
                                             f"{document.get('calibration')}, not for the model in use "
                                             f"({calibration or 'placed by hand'}): not restored")
            return None
        state = document["texture"]
        marks = len(state.get("marks") or [])
        self._restored = (calibration, marks)
        self.on_event("texture_restored", f"{marks} mark(s) learned on the print for calibration {calibration} "
                                          f"restored from {self.path.name} (saved {document.get('saved', '?')})")
        return state

    def ignored(self, calibration: str | None, reason: str) -> None:
        """The tracker could not take the saved state (core/texture.py said why)."""
        self._restored = (calibration, 0)
        self.on_event("texture_ignored", f"the marks saved in {self.path.name} do not fit the model of calibration "
                                         f"{calibration} ({reason}): not restored")

    def switch(self, switch_model: Callable[[], T]) -> T:
        """Run the model switch (which removes the file) with no save in between; what was restored at
        start is then history."""
        with self.lock:
            done = switch_model()
            self._restored, self._written = (None, 0), None
            return done

    # -- while running -----------------------------------------------------------------------
    def save(self, snapshot: TextureSnapshot | None, force: bool = False) -> None:
        """Write ``snapshot`` if it is new, belongs to the active calibration, and the last write was
        ``SAVE_EVERY_S`` ago (``force``: now, at shutdown). A disk that refuses is the storage fault;
        the snapshot is tried again after ``SAVE_EVERY_S``."""
        if snapshot is None or snapshot is self._written:
            return
        self._newest = snapshot
        now = self.clock()
        if not force and now - self._last_try < SAVE_EVERY_S:
            return
        with self.lock:
            if snapshot.calibration != self.storage.active_id():
                return  # an old model's tracker, its file removed by the switch: nothing to keep
            written = self._written
            unchanged = written is not None and written.calibration == snapshot.calibration and \
                written.state == snapshot.state  # refined to the same figures: nothing to write
            if unchanged or (not snapshot.state["marks"] and not self.path.exists()):
                self._written = snapshot
                return
            self._last_try = now
            try:
                self.storage.check_home()
                document = {"calibration": snapshot.calibration, "model_sha256": model_digest(self.storage),
                            "saved": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "texture": snapshot.state}
                write_atomic(self.path, json.dumps(document, separators=(",", ":")))
            except OSError as exc:
                failure = self.health.failed(exc)
                then = "lost with this shutdown" if force else f"kept in memory, tried again in {SAVE_EVERY_S:g} s"
                log.warning("the print texture learned could not be saved (%s): %s", failure or describe(exc), then)
                return
            self._written = snapshot

    # -- what the status shows ------------------------------------------------------------------
    def status(self, snapshot: TextureSnapshot | None) -> dict[str, Any] | None:
        """``/api/status``'s ``texture``: how many marks, the footprint, the newest marks (where, how deep,
        how sure), and whether the newest state is on disk."""
        if snapshot is None:
            return None
        marks = [mark["describe"] for mark in snapshot.state["marks"]]
        newest = sorted(marks, key=lambda mark: mark["learned_at"], reverse=True)[:NEWEST]
        restored_for, restored = self._restored
        return {"calibration": snapshot.calibration, "marks": len(marks),
                "footprint_scale": snapshot.state["grid"]["scale"],
                "newest": [{key: mark[key] for key in SHOWN} for mark in newest],
                "saved": snapshot is self._written, "restored": restored if restored_for == snapshot.calibration else 0}
