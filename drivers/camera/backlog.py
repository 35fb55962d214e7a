"""Frames a camera has delivered that no read has taken yet, handed out oldest first within a lag budget.

Why a budget and not "newest only": a host thread woken a millisecond late (the scheduler, another
thread holding the GIL) must not lose the frames the camera took meanwhile; a real camera's buffer
pool keeps them, and a position sensor that skipped them would report a gap where it could report
every exposure, each with its own mid-exposure time. Why not "every frame, however old": a reader
that falls behind for good (a slow consumer, a stall of seconds) must not serve ever older
positions. So a read takes the oldest frame delivered within ``max_lag_s`` of now, and skips (the
caller counts them as dropped, by frame id) the ones delivered before that; when every waiting
frame is older than that (a stall long enough to fill the camera's own buffer pool), it takes the
newest of them. ``max_lag_s = 0`` is "newest only".
"""

from __future__ import annotations

import math
from collections import deque
from typing import Generic, TypeVar

Item = TypeVar("Item")

DEFAULT_MAX_LAG_S = 0.02  # 20 frames at 1 kHz, one at 50 Hz: covers a late wake-up, not a stall
MAX_BACKLOG = 256  # frames held at most, whatever the budget (full images may be large)


class Backlog(Generic[Item]):
    """A bounded, time-ordered queue of delivered frames (or what a driver keeps of them)."""

    def __init__(self, capacity: int = MAX_BACKLOG) -> None:
        self._items: deque[tuple[float, Item]] = deque(maxlen=max(1, capacity))

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        self._items.clear()

    def push(self, delivered: float, item: Item, max_lag_s: float) -> None:
        """Keep ``item``, delivered (on the host) at ``delivered``; what no later read can take goes at once."""
        self._items.append((delivered, item))
        self._trim(delivered - max_lag_s)

    def take(self, max_lag_s: float, now: float) -> Item | None:
        """The oldest item delivered within ``max_lag_s`` of ``now`` (else the newest), or None when nothing waits."""
        self._trim(now - max_lag_s)
        return self._items.popleft()[1] if self._items else None

    def _trim(self, oldest_kept: float) -> None:
        """Drop items delivered before ``oldest_kept``, never the newest."""
        items = self._items
        while len(items) > 1 and items[0][0] < oldest_kept:
            items.popleft()


def first_slot(newest: int, next_unread: int, max_lag_s: float, period_s: float) -> int:
    """For a camera on a fixed frame clock (slot k delivered at k·period_s): the slot a read hands
    out under the same policy. ``newest`` is the newest delivered slot, ``next_unread`` the one
    after the last handed out."""
    lag_slots = math.floor(max_lag_s / period_s + 1e-9) if period_s > 0 else 0
    return max(next_unread, newest - lag_slots)
