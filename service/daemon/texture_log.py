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

from graytrack.service.daemon.map_store import MapLog


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


class TextureLog(MapLog):
    """``observe(texture)`` after each tracked frame: the tracker's new texture events, as events
    (:class:`MapLog` with the texture's sentences)."""

    def __init__(self, on_event: Callable[[str, str], None]) -> None:
        from graytrack.service.daemon.texture_store import TEXTURE

        super().__init__(TEXTURE, on_event)
