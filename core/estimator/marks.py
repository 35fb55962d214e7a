"""What a learned map holds, as marks told as they change: the part both of the estimator's maps share.

A map (the sensor's side, sensor_map.py; the print, print_map.py) holds a change at many places, each with its
variance; a person, and the daemon's event log, want it as *marks*: each run of neighbouring places the map has
learned along one row, with its figures and their σ. :class:`ToldMarks` keeps what was last told and, at each
:meth:`ToldMarks.look`, says what is new (``learned``), what moved beyond its σ (``changed``) and what the map let go
(``dropped``). The map says what a mark is (its ``marks()``, the keys of its place and figures: :class:`MarkShape`);
the telling is here, once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

CHANGED_Z = 3.0  # a told mark whose figure moved by this many σ (its told and its present one combined) has
# changed (more landed on it, part of it went); less is the filter refining what it had


@dataclass(frozen=True)
class MarkShape:
    """The keys of a map's marks: ``first``, ``last``: its first and last place along its row (inclusive, counted
    in the map's places); ``extent``: what follows the mark as the filter refines it (its place and size);
    ``figures``: (value, σ) pairs a change is judged on."""

    first: str
    last: str
    extent: tuple[str, ...]
    figures: tuple[tuple[str, str], ...]

    def overlap(self, a: dict[str, Any], b: dict[str, Any]) -> bool:
        return a["row"] == b["row"] and a[self.first] <= b[self.last] and b[self.first] <= a[self.last]

    def moved(self, told: dict[str, Any], now: dict[str, Any]) -> bool:
        return any(abs(now[value] - told[value]) > CHANGED_Z * math.hypot(told[sigma], now[sigma])
                   for value, sigma in self.figures)


def runs(flags: np.ndarray, stride: int) -> list[tuple[int, int]]:
    """(start, stop) of each run of True in ``flags``, a run never crossing from one row of ``stride`` to the next."""
    edges = np.diff(np.concatenate(([0], flags.astype(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    found = []
    for start, stop in zip(starts.tolist(), stops.tolist()):
        while start // stride != (stop - 1) // stride:  # split where a row ends
            end = (start // stride + 1) * stride
            found.append((start, end))
            start = end
        found.append((start, stop))
    return found


def figure(value: float) -> float:
    """``value`` to 4 significant figures (a mark's figures as told and kept: a σ keeps its size however small)."""
    return float(f"{value:.4g}")


class ToldMarks:
    """A map's marks as told. The map sets ``SHAPE`` (:class:`MarkShape`), has ``touched`` (a flag per place,
    ``stride`` places a row) and ``marks()``; :meth:`restore_told` after a restore (the restored marks are what
    the next look compares against: not told again)."""

    SHAPE: MarkShape
    touched: np.ndarray
    stride: int

    def marks(self) -> list[dict[str, Any]]:
        raise NotImplementedError

    @property
    def events(self) -> list[Any]:
        """What :meth:`look` found, in order (core/texture.py's :class:`TextureEvent`: frame, what, mark)."""
        if "_events" not in self.__dict__:
            self._events: list[Any] = []
        return self._events

    def restore_told(self) -> None:
        self._told = self.marks()

    def look(self, frame: int) -> list[Any]:
        """The marks now against those at the last look, as events of frame ``frame``: ``learned`` (a mark where
        none was), ``changed`` (a figure moved beyond ``CHANGED_Z`` of its σ since it was told, or marks merged),
        ``dropped`` (the map let all its places go: the frames speak for the calibration there again). A mark that
        only grew or shrank by a place or whose figures were refined is not told again, nor one whose places the
        map still holds but has not resolved again yet (a jump widened them: it waits, set aside, until the motion
        resolves it, then is told as changed if its figures moved): a mark near the resolution's threshold would
        otherwise be told dropped and learned again frame after frame."""
        from graytrack.core.texture import TextureEvent

        shape = self.SHAPE
        told: list[dict[str, Any]] = self.__dict__.get("_told", [])
        found: list[Any] = []
        kept: list[dict[str, Any]] = []
        matched: set[int] = set()
        for mark in self.marks():
            over = [i for i, old in enumerate(told) if shape.overlap(old, mark)]
            matched.update(over)
            if not over:
                found.append(TextureEvent(frame, "learned", mark))
                kept.append(mark)
            elif len(over) > 1 or shape.moved(told[over[0]], mark):
                found.append(TextureEvent(frame, "changed", mark))
                kept.append(mark)
            else:  # the same mark refined: its extent followed, its figures as last told
                kept.append({**told[over[0]], **{key: mark[key] for key in shape.extent}})
        for i, old in enumerate(told):
            if i in matched:
                continue
            start = old["row"] * self.stride
            if self.touched[start + old[shape.first]:start + old[shape.last] + 1].any():
                kept.append(old)  # held by the map, not resolved again yet
            else:
                found.append(TextureEvent(frame, "dropped", old))
        self._told = kept
        self.events.extend(found)
        return found


__all__ = ["CHANGED_Z", "MarkShape", "ToldMarks", "figure", "runs"]
