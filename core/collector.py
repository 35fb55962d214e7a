"""The cyclic garbage collector held off while a loop builds records frame by frame: in a process that is the
loop's own (the ``track`` command), never in the library's loop, which a daemon's other threads share the process
with.

A track keeps a few containers a frame to its end (the frame's estimate and its state's tuples): the collector's
passes over its youngest generation then come every couple of hundred frames, and each walks every container made
since, its older generations' passes the records kept so far; measured, 3-6 % of a frame's time on a 100-pixel
line. A frame's own objects make no reference cycle (reference counting frees them as it goes), so nothing waits
for the collector while it is held off; it runs again, as it was, once the loop is done.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def collector_paused() -> Iterator[None]:
    """The cyclic collector off for the block, then as it was (on where it was on: nested, the outermost turns it
    on again; another thread's pause ending first turns it on early, which costs only speed)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()
