"""The sensor's map the daemon learned, kept as part of the model of record (``DATA/sensor_map.json``).

Dust on the camera's window, a veil on it: the estimator learns a gain and an offset for each sample
they sit on once the motion has told them from the print (core/estimator/sensor_map.py). The map is
kept, restored, dropped and saved as every learned map is (:mod:`map_store`); what is its own is
here: its events' sentences (which map, where: the row and the pixels, how much: the gain and the
offset, how sure: their σ), what the status shows of it, and that a map is refined while anything
has landed on it.
"""

from __future__ import annotations

from typing import Any

from graytrack.service.daemon.map_store import SHOWN_MARKS, MapKind, told

def describe(what: str, mark: dict[str, Any]) -> str:
    """One sentence for an event of the sensor map's ``events`` (core/estimator/sensor_map.py: ``look``)."""
    where = f"at row {mark['row']}, pixels {mark['first_px']}-{mark['last_px']}"
    figures = (f"gain {mark['gain']:.3f} +/- {mark['gain_sigma']:.3f}, offset {mark['offset_gray']:+.1f} "
               f"+/- {mark['offset_sigma_gray']:.1f} gray")
    return told(what, "the sensor's side", "fixed in pixels: the camera's window", where, figures)


def status(state: dict[str, Any]) -> dict[str, Any]:
    """Samples touched (something landed on them) and learned (resolved by the motion), and the marks."""
    marks = state["marks"]
    return {"touched_samples": len(state["touched"]), "learned_samples": int(sum(state["learned"])),
            "marks": len(marks), "shown": sorted(marks, key=lambda mark: mark["samples"], reverse=True)[:SHOWN_MARKS]}


SENSOR_MAP = MapKind("sensor_map", "mark(s) learned on the sensor's side", status,
                     lambda sensor: bool(sensor.active), describe, lambda sensor: len(sensor.marks()))
