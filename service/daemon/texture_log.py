"""The event log's account of what the tracker learns on the print (core/texture.py).

A mark learned into the model changes what every later position rests on, so the daemon says so
as it happens: where on the print, how deep, how sure, and from how many frames (``texture_learned``);
a mark that changed (more dust landed on it: relearnt) or stopped fitting (dropped); the pixels'
footprint the marks showed. What the tracker learned belongs to the model it tracks with: when
another model takes over (a new calibration, or an earlier one activated: a rollback) the marks go
with the old tracker, and the log says how many were dropped.
"""

from __future__ import annotations

from typing import Any, Callable

from graytrack.core.texture import Texture

KINDS = {"learned": "texture_learned", "changed": "texture_changed", "dropped": "texture_dropped",
         "footprint": "texture_footprint"}


def describe(what: str, mark: dict[str, Any]) -> str:
    """One sentence for an event of :attr:`Texture.events`."""
    if what == "footprint":
        return (f"the pixels' footprint on the print is {mark['scale']:.5f} x the model's (the marks agree "
                f"best there, by chi2 {mark['chi2_gain']:.0f})")
    where = f"at x_w = {mark['x_mm']:.3f} mm ({mark['from_mm']:.3f}-{mark['to_mm']:.3f} mm)"
    deep = f"{100 * mark['depth']:.1f} % +/- {100 * mark['depth_sigma']:.1f} % of the light"
    seen = f"{mark['frames']} frames over {mark['travel_px']:.1f} px of travel"
    if what == "learned":
        return f"learned a mark on the print {where}, {deep}, from {seen}; its samples count again"
    if what == "changed":
        return f"the mark {where} changed (more landed on it): its samples are set aside until it is relearnt"
    return f"the mark {where} stopped fitting the frames: dropped, its samples set aside again"


class TextureLog:
    """``observe(texture)`` after each tracked frame: the tracker's new texture events, as events."""

    def __init__(self, on_event: Callable[[str, str], None]) -> None:
        self.on_event = on_event
        self._texture: Texture | None = None
        self._told = 0  # events of that texture already logged

    def observe(self, texture: Texture | None) -> None:
        if texture is not self._texture:
            self._texture, self._told = texture, 0
        if texture is None or len(texture.events) == self._told:
            return
        for event in texture.events[self._told:]:
            self.on_event(KINDS[event.what], f"frame {event.frame}: {describe(event.what, event.mark)}")
        self._told = len(texture.events)

    def replaced(self, reason: str) -> None:
        """Another model takes over: what the old one learned goes with it."""
        texture, self._texture, self._told = self._texture, None, 0
        if texture is not None and texture.learned:
            self.on_event("texture_dropped", f"{len(texture.learned)} mark(s) learned on the print dropped with the "
                                             f"model they were learned for ({reason})")
