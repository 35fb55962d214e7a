"""The print texture the daemon learned, kept as part of the model of record (``DATA/texture.json``).

A mark learned on the print (dust settled on it: core/texture.py) is kept, restored, dropped and
saved as every learned map is (:mod:`map_store`); what is the texture's own is here: how its state
is counted and shown, and that a texture is refined while it holds learned marks.
"""

from __future__ import annotations

from typing import Any, Callable

from graytrack.core.texture import Texture
from graytrack.service.daemon.datadir import DataDirHealth
from graytrack.service.daemon.map_store import SAVE_EVERY_S, MapKind, MapSnapshot, MapSnapshotter, MapStore
from graytrack.service.daemon.storage import Storage
from graytrack.service.daemon.texture_log import describe

NEWEST = 3  # marks the status shows (the newest learned)
SHOWN = ("x_mm", "from_mm", "to_mm", "depth", "depth_sigma", "frames", "learned_at")  # of each, what status shows


def status(state: dict[str, Any]) -> dict[str, Any]:
    """How many marks, the footprint, the newest marks (where, how deep, how sure)."""
    marks = [mark["describe"] for mark in state["marks"]]
    newest = sorted(marks, key=lambda mark: mark["learned_at"], reverse=True)[:NEWEST]
    return {"marks": len(marks), "footprint_scale": state["grid"]["scale"],
            "newest": [{key: mark[key] for key in SHOWN} for mark in newest]}


def _learned(texture: Texture) -> int:
    return len(texture.learned)


TEXTURE = MapKind("texture", "mark(s) learned on the print", status, lambda texture: bool(texture.learned), describe,
                  _learned)
TextureSnapshot = MapSnapshot


class TextureSnapshotter(MapSnapshotter):
    def __init__(self) -> None:
        super().__init__(TEXTURE)


class TextureStore(MapStore):
    def __init__(self, storage: Storage, health: DataDirHealth, clock: Callable[[], float],
                 on_event: Callable[[str, str], None]) -> None:
        super().__init__(TEXTURE, storage, health, clock, on_event)


__all__ = ["SAVE_EVERY_S", "TEXTURE", "TextureSnapshot", "TextureSnapshotter", "TextureStore"]
