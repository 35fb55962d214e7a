"""The daemon's data directory: the current model, the bearer token and every calibration run.

Layout::

    DATA/lock                       held (flock) by the one daemon using this directory; has its pid
    DATA/token                      bearer token, mode 0600, generated at first start
    DATA/model.json                 the model the daemon tracks with (loaded at start)
    DATA/active                     the id of the calibration that model came from
    DATA/texture.json               marks the tracker learned on the print with that model (texture_store.py)
    DATA/sensor_map.json            the sensor's side the estimator learned with that model (sensor_map_store.py)
    DATA/print_map.json             the print the estimator learned with that model (print_map_store.py)
    DATA/calibrations/<id>/         one sweep: status.json, recording.npz, model.json, report.json(, report.html)

Everything is written atomically (temporary file + rename), so a crash or a full disk never leaves
a half-written model that would be loaded at the next start. Calibration ids sort by time, which
is what "latest" means.
"""

from __future__ import annotations

import errno
import fcntl
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
from graytrack.core.models import load_model
from graytrack.core.models.fourier import FourierModel
from graytrack.service.daemon.datadir import identity
from graytrack.service.daemon.errors import DataDirInUse, UnsafeDataDir
from graytrack.service.daemon.switch import Switch, leftovers

LEARNED_MAPS = ("texture", "sensor_map", "print_map")  # the maps learned with a model (map_store.py's kinds):
# each goes with the model at a switch, since marks learned against one model sit elsewhere on another's

log = logging.getLogger("graytrack.daemon")
CALIBRATION_ID = re.compile(r"^\d{8}T\d{6}\d{6}Z$")


def private(path: Path, what: str, forbidden_mode: int, fix: str) -> None:
    """Refuse ``path`` when another user owns it or may change it (as ssh refuses a key file): in a
    directory others can write, anyone could plant the token that then moves the stage."""
    info = path.stat()
    if info.st_uid != os.geteuid():
        raise UnsafeDataDir(f"{what} {path} is owned by uid {info.st_uid}, not by this user (uid {os.geteuid()}): "
                            f"use a directory of your own (--data-dir) or chown it")
    if info.st_mode & forbidden_mode:
        given = info.st_mode & forbidden_mode
        could = " and ".join(verb for verb, bits in (("read", 0o044), ("change", 0o022)) if given & bits) or "use"
        raise UnsafeDataDir(f"{what} {path} has mode {info.st_mode & 0o777:o}: other users could {could} it; "
                            f"fix: {fix}")


class Storage:
    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True, mode=0o700)  # holds the token
        private(self.root, "data directory", 0o022, f"chmod go-w {self.root}")
        self.calibrations = self.root / "calibrations"
        self.calibrations.mkdir(exist_ok=True)
        self.home = identity(self.root)  # the directory opened, whatever its path leads to later (datadir.py)
        self._last_time: datetime | None = None
        self._lock_fd: int | None = None

    # -- token -----------------------------------------------------------------------------
    @property
    def token_path(self) -> Path:
        return self.root / "token"

    def token(self) -> tuple[str, bool]:
        """The stored token, created (mode 0600, never readable by others) if missing; ``(token, created)``.

        Created whole or not at all: the token is written to a private temporary file which is then
        hard-linked to its name, an atomic create-if-absent, so a concurrent first start reads either
        no file or the complete one, never an empty one.
        """
        if not self.token_path.exists():
            token = secrets.token_urlsafe(32)
            tmp = self.root / f".token.{os.getpid()}.{secrets.token_hex(4)}.tmp"
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            try:
                with os.fdopen(fd, "w") as fh:
                    fh.write(token + "\n")
                    fh.flush()
                    os.fsync(fh.fileno())
                os.link(tmp, self.token_path)
                return token, True
            except FileExistsError:
                pass
            finally:
                tmp.unlink(missing_ok=True)
        private(self.token_path, "token file", 0o077, f"chmod 600 {self.token_path}")
        try:
            token = self.token_path.read_text().strip()
        except UnicodeDecodeError:
            raise GraytrackError(f"{self.token_path}: not a text token; delete it to regenerate") from None
        if len(token) < 16:
            raise GraytrackError(f"{self.token_path}: token shorter than 16 characters; delete it to regenerate")
        return token, False

    # -- one daemon per directory -----------------------------------------------------------
    @property
    def lock_path(self) -> Path:
        return self.root / "lock"

    def lock(self) -> None:
        """Hold this directory for this process (released when it exits, however it exits).

        Raises :class:`DataDirInUse` naming the holder's pid: two daemons on one directory would
        overwrite each other's model and calibrations.
        """
        fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EACCES):
                raise DataDirInUse(f"data directory {self.root} is in use by another graytrack serve "
                                   f"(pid {holder})") from None
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._lock_fd = fd

    def unlock(self) -> None:
        fd, self._lock_fd = self._lock_fd, None
        if fd is not None:
            os.close(fd)

    # -- current model ---------------------------------------------------------------------
    @property
    def model_path(self) -> Path:
        return self.root / "model.json"

    def load_current_model(self) -> FourierModel | None:
        """The saved model, or None when there is none; an unreadable one raises (the rig says why)."""
        if not self.model_path.exists():
            return None
        return load_model(self.model_path)

    def copy_model_of(self, calibration_id: str) -> None:
        """``model.json`` becomes a byte-for-byte copy of that calibration's model."""
        write_atomic(self.model_path, (self.calibration_dir(calibration_id) / "model.json").read_bytes())

    @property
    def learned_map_paths(self) -> tuple[Path, ...]:
        """The files of the maps learned with the model in use (``DATA/<name>.json``, map_store.py's kinds)."""
        return tuple(self.root / f"{name}.json" for name in LEARNED_MAPS)

    def switch_model(self, calibration_id: str) -> Switch:
        """``active`` and ``model.json`` become that calibration's, both or neither (:mod:`switch`): the
        pointer first, then the copy; the maps learned with the old model (the print's texture, the
        sensor's map) go with it. The
        returned switch is applied; ``undo()`` takes all back without needing space (until ``commit()``)."""
        self.check_home()
        source = (self.calibration_dir(calibration_id) / "model.json").read_bytes()
        return Switch([(self.active_path, (calibration_id + "\n").encode()), (self.model_path, source),
                       *((path, None) for path in self.learned_map_paths)]).apply()

    def check_home(self) -> None:
        """Raise when the path no longer leads to the directory opened at start (removed, replaced): no
        write goes into a deleted directory or a stranger's."""
        try:
            same = identity(self.root) == self.home
        except FileNotFoundError:
            same = False
        if not same:
            raise FileNotFoundError(errno.ENOENT, "the data directory was removed or replaced", str(self.root))

    def reconcile_model(self) -> tuple[FourierModel | None, str | None]:
        """The model to track with, and what was set right when the directory disagreed with itself.

        ``active`` is the one pointer an install switches; the model of record is that calibration's
        own ``model.json``, and ``DATA/model.json`` a copy of it. After a crash anywhere in an install
        the pointer names either a calibration that finished ``done`` (its model is the one) or one
        that did not (the install never completed: back to the newest calibration that did). A
        ``DATA/model.json`` with no calibration behind it (placed by hand) is used as it is.
        """
        for path in leftovers(self.root, (self.active_path.name, self.model_path.name)):  # a switch killed half-way
            path.unlink(missing_ok=True)
        done = [i for i in self.calibration_ids()
                if (self.read_status(i) or {}).get("state") == "done"
                and (self.calibration_dir(i) / "model.json").is_file()]
        active = self.active_id()
        chosen = active if active in done else (done[-1] if done else None)
        notes = []
        if chosen is None:
            if active is not None:
                self.active_path.unlink(missing_ok=True)
                notes.append(f"the active calibration {active} never finished installing and no earlier one did")
            return self.load_current_model(), "; ".join(notes) or None
        model = load_model(self.calibration_dir(chosen) / "model.json")
        if chosen != active:
            self.set_active(chosen)
            notes.append(f"the active calibration {active or '(none)'} never finished installing: "
                         f"back to calibration {chosen}, the newest one that did")
        source = (self.calibration_dir(chosen) / "model.json").read_bytes()
        if not self.model_path.is_file() or self.model_path.read_bytes() != source:
            self.copy_model_of(chosen)
            notes.append(f"model.json was not calibration {chosen}'s model: restored from it")
        return model, "; ".join(notes) or None

    # -- the active calibration --------------------------------------------------------------
    @property
    def active_path(self) -> Path:
        return self.root / "active"

    def set_active(self, calibration_id: str) -> None:
        """The calibration whose model ``model.json`` holds (written after the model, atomically)."""
        write_atomic(self.active_path, calibration_id + "\n")

    def active_id(self) -> str | None:
        try:
            value = self.active_path.read_text().strip()
        except OSError:
            return None
        return value if CALIBRATION_ID.match(value) else None

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
        self.check_home()
        write_atomic(self.calibration_dir(calibration_id) / "status.json",
                     json.dumps(document, indent=1, default=float))

    def read_status(self, calibration_id: str) -> dict[str, Any] | None:
        try:
            path = self.calibration_dir(calibration_id) / "status.json"
        except KeyError:
            return None
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError, RecursionError):  # missing, or not a document this daemon wrote
            return None

    def calibration_ids(self) -> list[str]:
        """Every calibration's id, oldest first."""
        return sorted(p.name for p in self.calibrations.iterdir() if CALIBRATION_ID.match(p.name))

    def latest_calibration_id(self) -> str | None:
        ids = self.calibration_ids()
        return ids[-1] if ids else None
