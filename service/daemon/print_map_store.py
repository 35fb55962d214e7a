"""The print's map the daemon learned, kept as part of the model of record (``DATA/print_map.json``).

Dust settling on the print, a smudge: the estimator learns a reflectance change at each place along the target
they lie at once the motion has carried them across the pixels (core/estimator/print_map.py). The map is kept,
restored, dropped and saved as every learned map is (:mod:`map_store`); what is its own is here: its events'
sentences (which map, where: the stretch of the target, how much: the reflectance, how sure: its σ), what the
status shows of it, and that a map is refined while anything has landed on it.
"""

from __future__ import annotations

from typing import Any

from graytrack.service.daemon.map_store import SHOWN_MARKS, MapKind, told

def describe(what: str, mark: dict[str, Any]) -> str:
    """One sentence for an event of the print map's ``events`` (core/estimator/marks.py: ``look``)."""
    where = f"at x_w = {mark['x_mm']:.4f} mm ({mark['from_mm']:.4f}-{mark['to_mm']:.4f} mm, row {mark['row']})"
    figures = f"reflectance {mark['reflectance']:.3f} +/- {mark['reflectance_sigma']:.3f}"
    return told(what, "the print", "it moves with the stage", where, figures)


def status(state: dict[str, Any]) -> dict[str, Any]:
    """Nodes touched (something landed on them) and learned (carried across the pixels and resolved), the marks."""
    marks = state["marks"]
    return {"touched_nodes": len(state["touched"]), "learned_nodes": int(sum(state["learned"])),
            "node_mm": state["node_mm"], "marks": len(marks),
            "shown": sorted(marks, key=lambda mark: mark["nodes"], reverse=True)[:SHOWN_MARKS]}


PRINT_MAP = MapKind("print_map", "mark(s) learned on the print", status, lambda printed: bool(printed.active),
                    describe, lambda printed: len(printed.marks()))
