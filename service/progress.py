"""Progress for long work, shown on stderr.

Core numerics report progress through a plain ``callback(fraction, label)`` so that they stay free
of I/O; this module is the terminal end of that callback.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO

ProgressCallback = Callable[[float, str], None]
# A line saying what a run did besides its outputs (a frame axis reversed, the grating moved to mid-exposure):
# the command line prints it, a batch worker keeps it in the recording's summary row (nobody reads its stdout).
NoteCallback = Callable[[str], None]


class ProgressBar:
    """A one-line bar on a terminal; throttled plain lines when stderr is a file or a pipe."""

    def __init__(self, title: str, stream: TextIO | None = None, width: int = 30, min_interval_s: float = 0.1):
        self.title = title
        self.stream = stream if stream is not None else sys.stderr
        self.width = width
        self.min_interval_s = min_interval_s if self.stream.isatty() else 2.0
        self._last_emit = -float("inf")
        self._last_percent = -1

    def __call__(self, fraction: float, label: str = "") -> None:
        fraction = min(max(fraction, 0.0), 1.0)
        now = time.monotonic()
        percent = int(round(100 * fraction))
        if fraction < 1.0 and (now - self._last_emit < self.min_interval_s or percent == self._last_percent):
            return
        self._last_emit, self._last_percent = now, percent
        if self.stream.isatty():
            filled = int(round(self.width * fraction))
            bar = "#" * filled + "-" * (self.width - filled)
            end = "\n" if fraction >= 1.0 else ""
            self.stream.write(f"\r{self.title} [{bar}] {percent:3d}% {label:<40.40}{end}")
        else:
            self.stream.write(f"{self.title}: {percent:3d}% {label}\n")
        self.stream.flush()
