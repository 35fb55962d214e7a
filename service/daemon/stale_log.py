"""The event log's account of the tracker's stale flag: a model gone stale, or a single frame.

Every position message carries its frame's flag as it is solved; the event log is what a person
reads afterwards, and there a flag that rose on one frame and cleared on the next (a grating
reading gone wrong, a frame placed wrong) is no model gone stale: logged as ``model_stale`` with the
family's advice ("recalibrate"), it sent people to recalibrate a model that holds. So a rise is
logged once the next frame says which it was: still flagged, ``model_stale`` (naming the frame it
began on); clear again, ``frame_flagged`` (that frame alone, the model holds).
"""

from __future__ import annotations

from typing import Callable

from graytrack.core.validity import ADVICE


class StaleLog:
    """``observe(frame_id, family)`` for each tracked frame (``family`` None: not flagged), in order."""

    def __init__(self, on_event: Callable[[str, str], None]) -> None:
        self.on_event = on_event
        self.family: str | None = None  # of the frame observed last
        self._began: int | None = None  # the frame the flag rose on, while it is not yet logged
        self._logged = False  # a model_stale event stands for the flag in force

    def observe(self, frame_id: int, family: str | None) -> None:
        before, self.family = self.family, family
        if before is None:
            if family is not None:
                self._began = frame_id  # one frame so far: the next tells a model gone stale from a single frame
            return
        if family is None:
            if self._logged:
                self.on_event("model_fresh", "the model holds again")
            else:
                self.on_event("frame_flagged", f"frame {self._began} flagged alone (cause: {before}), the frames "
                                               "around it not: a grating reading gone wrong or a frame placed wrong "
                                               "there; the model holds")
            self._logged, self._began = False, None
            return
        if not self._logged or family != before:
            since = f" since frame {self._began}" if not self._logged else ""
            self.on_event("model_stale", f"the model no longer holds{since} (stale, cause: {family}): {ADVICE[family]}")
            self._logged = True
