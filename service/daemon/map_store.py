"""What the daemon learns while tracking, kept as part of the model of record: one store for each learned map.

Maps are learned while running: the print's texture (marks on the target, core/texture.py, kept in
``DATA/texture.json``) by today's tracker; the sensor's map (a gain and an offset per sample on the camera's side,
core/estimator/sensor_map.py, kept in ``DATA/sensor_map.json``) and the print's map (a reflectance change per place
along the target, core/estimator/print_map.py, ``DATA/print_map.json``) by the estimator. Each is part of what every
later position rests on, as much as the model's coefficients: a daemon restarted on the same model would otherwise
set those samples aside again, lose or flag frames until it had relearnt each mark, and say nothing of why. So what the
live tracker learned is written beside the model, tied to the calibration it was learned for (its id and the
SHA-256 of ``DATA/model.json``), reloaded into the tracker at start for that calibration only, and removed by
the same switch that installs another model (a new calibration, a rollback: :meth:`Storage.switch_model`),
since marks learned against one model sit elsewhere on another's.

What differs between the two maps is a :class:`MapKind` (its file, its events' names, how its state is counted
and shown, whether a map is being refined); the keeping is the same and is here, once:

- the frame loop takes a :class:`MapSnapshot` when the map changes (:class:`MapSnapshotter`: an event of the
  map's, or every ``REFRESH_FRAMES`` frames while it is refined), never touching the disk, and logs the map's
  events as they come (:class:`MapLog`);
- the rig's watchdog hands the newest snapshot to :meth:`MapStore.save`, which writes it atomically at most
  every ``SAVE_EVERY_S`` (the first change at once). A full or read-only disk is the ``storage`` fault
  (:mod:`datadir`), the state stays in memory and the write is tried again: the daemon keeps tracking with
  what it learned;
- the model switch runs under every store's lock (:meth:`Stores.switch`), so a save never writes the old
  model's map after it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, TypeVar

from graytrack.core.files import write_atomic
from graytrack.service.daemon.datadir import DataDirHealth
from graytrack.service.daemon.storage import Storage
from graytrack.service.daemon.worker import describe

log = logging.getLogger("graytrack.daemon")
T = TypeVar("T")
SAVE_EVERY_S = 10.0  # at most one write in this long (the rig's clock): marks learned in a burst cost one write
SHOWN_MARKS = 10  # marks the status lists of a map (the widest first); all of them are in GET /api/maps
REFRESH_FRAMES = 500  # frames between two snapshots while a learned map is refined without an event


def told(what: str, side: str, nature: str, where: str, figures: str) -> str:
    """One sentence for an event of a map's marks (core/estimator/marks.py): ``what`` (learned, changed, dropped)
    of a mark on ``side`` (what it is: ``nature``) ``where`` with its ``figures`` (how much, how sure)."""
    if what == "learned":
        return f"learned a mark on {side} ({nature}) {where}: {figures}"
    if what == "changed":
        return f"the mark on {side} {where} changed (more landed on it, or part went): now {figures}"
    return f"the mark on {side} {where} ({figures}) no longer holds: the frames read as calibrated there again; dropped"


@dataclass(frozen=True)
class MapKind:
    """What differs between two learned maps. ``name``: the file's stem (``DATA/<name>.json``), the document's
    key and the events' prefix (``<name>_restored``, ``_ignored``, ``_learned``, …); ``marks``: what its
    marks are called in a sentence ("mark(s) learned on the print"); ``status``: the status document's own
    part made from a state (its counts, the marks it shows); ``refining``: whether a map is still being refined
    (snapshots are then taken every ``REFRESH_FRAMES`` frames even without an event); ``describe``: one
    sentence for one of the map's events (what, the mark's figures); ``learned``: how many marks a live map
    holds (said when another model takes it away)."""

    name: str
    marks: str
    status: Callable[[dict[str, Any]], dict[str, Any]]
    refining: Callable[[Any], bool]
    describe: Callable[[str, dict[str, Any]], str]
    learned: Callable[[Any], int]

    def file(self, storage: Storage) -> Path:
        return storage.root / f"{self.name}.json"

    def event(self, what: str) -> str:
        return f"{self.name}_{what}"


@dataclass(frozen=True)
class MapSnapshot:
    """What a tracker had learned at one frame, for the calibration ``calibration`` (None: a model
    placed by hand)."""

    calibration: str | None
    state: dict[str, Any]  # the map's state(): the document kept on disk (with a "marks" list)


class MapSnapshotter:
    """On the frame loop: ``observe`` after each tracked frame; ``latest`` is the newest snapshot."""

    def __init__(self, kind: MapKind) -> None:
        self.kind = kind
        self.latest: MapSnapshot | None = None
        self._map: Any = None
        self._events = 0
        self._frames = 0

    def observe(self, learned: Any, calibration: str | None) -> None:
        """``learned``: the tracker's map (with ``events`` and ``state()``), None when it keeps none."""
        if learned is None:
            self._map, self.latest = None, None
            return
        self._frames += 1
        changed = learned is not self._map or len(learned.events) != self._events
        if not changed and self._frames >= REFRESH_FRAMES and not self.kind.refining(learned):
            self._frames = 0  # nothing to refine: looked at again in REFRESH_FRAMES
        if not (changed or self._frames >= REFRESH_FRAMES):
            return
        self._map, self._events, self._frames = learned, len(learned.events), 0
        self.latest = MapSnapshot(calibration, learned.state())


class MapLog:
    """The event log's account of what the tracker learns into a map: ``observe(map)`` after each tracked
    frame logs its new events (``<name>_learned``, ``_changed``, ``_dropped``, …, one sentence each saying
    where, how much and how sure); ``replaced(reason)`` when another model takes over (what the old one
    learned goes with it, and the log says how many marks were dropped)."""

    def __init__(self, kind: MapKind, on_event: Callable[[str, str], None]) -> None:
        self.kind, self.on_event = kind, on_event
        self._map: Any = None
        self._told = 0  # events of that map already logged

    def observe(self, learned: Any) -> None:
        if learned is not self._map:
            self._map, self._told = learned, 0
        if learned is None or len(learned.events) == self._told:
            return
        for event in learned.events[self._told:]:
            sentence = self.kind.describe(event.what, event.mark)
            self.on_event(self.kind.event(event.what), f"frame {event.frame}: {sentence}")
        self._told = len(learned.events)

    def replaced(self, reason: str) -> None:
        """Another model takes over: what the old one learned goes with it."""
        learned, self._map, self._told = self._map, None, 0
        count = self.kind.learned(learned) if learned is not None else 0
        if count:
            self.on_event(self.kind.event("dropped"), f"{count} {self.kind.marks} dropped with the model they were "
                                                      f"learned for ({reason})")


def model_digest(storage: Storage) -> str | None:
    """SHA-256 of ``DATA/model.json`` (None: there is none)."""
    try:
        return hashlib.sha256(storage.model_path.read_bytes()).hexdigest()
    except FileNotFoundError:
        return None


class MapStore:
    def __init__(self, kind: MapKind, storage: Storage, health: DataDirHealth, clock: Callable[[], float],
                 on_event: Callable[[str, str], None]) -> None:
        self.kind, self.storage, self.health, self.clock, self.on_event = kind, storage, health, clock, on_event
        self.lock = threading.Lock()  # held by a save and by the model switch (``switch``)
        self._written: MapSnapshot | None = None  # the snapshot on disk (None: none of this run)
        self._last_try = -math.inf
        self._restored: tuple[str | None, int] = (None, 0)  # (calibration, marks) restored at start
        self._newest: MapSnapshot | None = None  # the newest snapshot handed to save

    def newest(self, calibration: str | None) -> dict[str, Any] | None:
        """The newest state learned for ``calibration`` (a frame loop restarted goes on from it)."""
        newest = self._newest or self._written
        return newest.state if newest is not None and newest.calibration == calibration else None

    @property
    def path(self) -> Path:
        return self.kind.file(self.storage)

    # -- at start ----------------------------------------------------------------------------
    def load(self, calibration: str | None) -> dict[str, Any] | None:
        """The state saved for ``calibration`` (the active one, whose model is in ``DATA/model.json``),
        or None: none saved, or saved for another model (said, and left for the next save to replace)."""
        ignored, name = self.kind.event("ignored"), self.path.name
        try:
            document = json.loads(self.path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError, RecursionError) as exc:
            self.on_event(ignored, f"{name} cannot be read ({describe(exc)}): the {self.kind.marks} before this "
                                   f"start are not restored")
            return None
        if not isinstance(document, dict) or not isinstance(document.get(self.kind.name), dict) or \
                not isinstance(document[self.kind.name].get("marks"), list):
            self.on_event(ignored, f"{name} is not a {self.kind.name} this daemon wrote: not restored")
            return None
        if document.get("calibration") != calibration or document.get("model_sha256") != model_digest(self.storage):
            self.on_event(ignored, f"{name} holds {self.kind.marks} for calibration {document.get('calibration')}, "
                                   f"not for the model in use ({calibration or 'placed by hand'}): not restored")
            return None
        state = document[self.kind.name]
        marks = len(state["marks"])
        self._restored = (calibration, marks)
        self.on_event(self.kind.event("restored"), f"{marks} {self.kind.marks} for calibration {calibration} "
                                                   f"restored from {name} (saved {document.get('saved', '?')})")
        return state

    def ignored(self, calibration: str | None, reason: str) -> None:
        """The tracker could not take the saved state (the map said why)."""
        self._restored = (calibration, 0)
        self.on_event(self.kind.event("ignored"), f"the {self.kind.marks} saved in {self.path.name} do not fit the "
                                                  f"model of calibration {calibration} ({reason}): not restored")

    def forget(self) -> None:
        """The model switch removed the file (under the lock, :class:`Stores`): what was restored at start is
        history."""
        self._restored, self._written = (None, 0), None

    # -- while running -----------------------------------------------------------------------
    def save(self, snapshot: MapSnapshot | None, force: bool = False) -> None:
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
                            "saved": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                            self.kind.name: snapshot.state}
                write_atomic(self.path, json.dumps(document, separators=(",", ":")))
            except OSError as exc:
                failure = self.health.failed(exc)
                then = "lost with this shutdown" if force else f"kept in memory, tried again in {SAVE_EVERY_S:g} s"
                log.warning("the %s could not be saved (%s): %s", self.kind.marks, failure or describe(exc), then)
                return
            self._written = snapshot

    # -- what the status shows ------------------------------------------------------------------
    def status(self, snapshot: MapSnapshot | None) -> dict[str, Any] | None:
        """``/api/status``'s part for this map: the kind's own figures, the calibration it was learned for,
        whether the newest state is on disk and how many marks were restored at this start."""
        if snapshot is None:
            return None
        restored_for, restored = self._restored
        return {"calibration": snapshot.calibration, **self.kind.status(snapshot.state),
                "saved": snapshot is self._written, "restored": restored if restored_for == snapshot.calibration else 0}


class Stores:
    """Every map's store, switched together: the model switch removes every map's file, under every store's lock."""

    def __init__(self, *stores: MapStore) -> None:
        self.stores = stores

    def switch(self, switch_model: Callable[[], T]) -> T:
        locks = [store.lock for store in self.stores]
        for lock in locks:
            lock.acquire()
        try:
            done = switch_model()
            for store in self.stores:
                store.forget()
            return done
        finally:
            for lock in reversed(locks):
                lock.release()
