"""Several files of one directory replaced as one step, with an undo that needs no space.

Why: the tracked model is two files, ``DATA/active`` (the pointer) and ``DATA/model.json`` (a copy
of that calibration's model). Written one after the other, a full disk between the two left the
pointer on the new calibration and the old model in the tracker. Here every byte is written first
(temporary files next to the targets: the only step that needs space, undone by deleting them),
the files being replaced are kept by hard links (no space), and only then are the new files
renamed over the old ones: renames allocate nothing, and ``undo`` renames the kept links back.
A crash between two renames leaves the pointer moved first, which the start-up reconciliation
(``Storage.reconcile_model``) completes or takes back.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path


def _write_synced(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        view = memoryview(data)
        while view:  # a full disk raises ENOSPC here
            view = view[os.write(fd, view):]
        os.fsync(fd)
    finally:
        os.close(fd)


def leftovers(folder: Path, names: tuple[str, ...]) -> list[Path]:
    """What a switch killed half-way (kill -9, power) left of ``names`` in ``folder`` (removed at the next start)."""
    return [p for name in names for p in folder.glob(f".{name}.*.*") if p.suffix in (".new", ".old")]


class Switch:
    """Replace ``targets`` (in order) by ``contents``; ``commit()`` forgets the old files, ``undo()`` restores them."""

    def __init__(self, changes: list[tuple[Path, bytes | None]]) -> None:
        """``changes``: (target, new content, or None to remove it). Nothing is changed if this raises."""
        tag = f"{os.getpid()}.{secrets.token_hex(4)}"
        self._new: list[tuple[Path, Path | None]] = []
        self._kept: list[tuple[Path, Path | None]] = []
        self._done = 0
        try:
            for target, content in changes:
                new = None
                if content is not None:
                    new = target.with_name(f".{target.name}.{tag}.new")
                    self._new.append((target, new))
                    _write_synced(new, content)
                else:
                    self._new.append((target, None))
                kept = target.with_name(f".{target.name}.{tag}.old") if target.exists() else None
                if kept is not None:
                    os.link(target, kept)
                self._kept.append((target, kept))
        except BaseException:
            self._forget(new=True)
            raise

    def apply(self) -> "Switch":
        """The renames (the targets change now, in order); undone if one of them fails."""
        try:
            for target, new in self._new:
                if new is None:
                    target.unlink(missing_ok=True)
                else:
                    os.replace(new, target)
                self._done += 1
        except BaseException:
            self.undo()
            raise
        return self

    def undo(self) -> None:
        """Every target back to what it was (renames and unlinks only: works on a full disk)."""
        for target, kept in self._kept[: self._done][::-1]:
            if kept is None:
                target.unlink(missing_ok=True)
            else:
                os.replace(kept, target)
        self._done = 0
        self._forget(new=True)

    def commit(self) -> None:
        self._forget(new=False)

    def _forget(self, new: bool) -> None:
        for _, path in (self._new if new else []) + self._kept:
            if path is not None:
                path.unlink(missing_ok=True)
