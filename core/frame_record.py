"""The per-frame record: every quantity tracking gives a frame, with its unit in its name and one
type wherever it goes.

Live tracking (:class:`~graytrack.core.tracking.LiveFix`), batch tracking
(:class:`~graytrack.core.tracking.TrackResult`, one array per quantity), the `track` CSV, the
daemon's position stream, ``fit`` in ``/api/status`` and ``/metrics`` all name a quantity as
:data:`QUANTITIES` does and give it the type it has here: a flag is a boolean (``true``/``false``
in JSON, 0/1 in the CSV), a count an integer, a figure a float or null when it does not exist
(never NaN in JSON), a reason a string or null. A new per-frame quantity is one entry here, one
field of ``LiveFix`` and ``TrackResult`` of the same name, and it reaches every output; the solver's
``FrameSolution`` and the monitor's ``FrameSign`` use the same names for what they share
(tests/core/test_frame_record.py holds every view to this table).

The one exception is the bound inside the solver, which works in millimetres (``crlb_mm``); it
leaves the core as ``crlb_um``, converted here and nowhere else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy is imported where the columns are made: the client reads QUANTITIES without it
    import numpy as np


@dataclass(frozen=True)
class Quantity:
    name: str  # with its unit: x_mm, crlb_um, focus_px2
    kind: type  # float, int, bool or str
    description: str
    fit: bool = True  # one of the tracker's fit figures ("fit" in /api/status, the stream's extras)
    csv: bool = True  # a column of the `track` CSV (in this order; docs/contracts.md)


# In the `track` CSV's order: the placement first (the grating's reference_mm and error_um follow
# it there), then the fit figures; a new quantity goes at the end.
QUANTITIES: tuple[Quantity, ...] = (
    Quantity("x_mm", float, "position of the stage; null when the frame could not be placed", fit=False),
    Quantity("locked", bool, "the tracker is locked: the position follows from the last one", fit=False),
    Quantity("rms_gray", float, "residual rms of the frame against the model", fit=False),
    Quantity("crlb_um", float, "Cramér–Rao bound of this frame: the noise floor of its position", fit=False),
    Quantity("chi2", float, "weighted residual per sample against the noise model (≈ 1 when the model holds)"),
    Quantity("rejected_px", int, "samples the robust solve set aside"),
    Quantity("gain", float, "light relative to calibration (1 unless re-solved)"),
    Quantity("offset_gray", float, "light offset relative to calibration (0 unless re-solved)"),
    Quantity("stale", bool, "the validity monitor says the model no longer describes the images"),
    Quantity("stale_reason", str, "while stale: the family of causes (transients, pixels, light, focus, magnification, "
                                  "scale, geometry, period, texture); null otherwise"),
    Quantity("transient_px", int, "of the samples set aside, those of a compact transient (a glint, passing dust)"),
    Quantity("focus_px2", float, "change of blur variance since calibration, px²; null when not estimated"),
    Quantity("focus_sigma_px2", float, "its standard error, px²; null when not estimated"),
    Quantity("texture_px", int, "samples a mark learned on the print corrected (core/texture.py; in the CSV with "
                                "learning on)"),
    Quantity("iterations", int, "Gauss–Newton iterations the solve took", fit=False, csv=False),
    # Carried where they exist, appended by their own producers (the CSV's --trim and no-grating columns):
    Quantity("slide_sigma_um", float, "without a grating: what a magnification change could slide the image by "
                                      "(in crlb_um too; core/slide.py)", fit=False, csv=False),
    Quantity("trim_um", float, "the online trim's correction of this position (--trim, [daemon] trim)", fit=False,
             csv=False),
    Quantity("trim_sigma_um", float, "what the trim adds to the bound: its uncertainty and lag", fit=False, csv=False),
)
PLACEMENT = ("x_mm", "locked", "rms_gray", "crlb_um")  # the CSV's first record columns, before the grating's
BY_NAME = {quantity.name: quantity for quantity in QUANTITIES}
FIT = tuple(quantity.name for quantity in QUANTITIES if quantity.fit)
SOLVER_UNITS = {"crlb_um": ("crlb_mm", 1e3)}  # record name: (the core's attribute, factor to the record's unit)


def typed(name: str, value: Any) -> bool | int | float | str | None:
    """``value`` as the record's type for ``name``: JSON-safe (no NaN), the same in every output."""
    kind = BY_NAME[name].kind
    if value is None:
        return None
    if kind is bool:
        return bool(value)
    if kind is str:
        return str(value) or None
    number = float(value)
    if not math.isfinite(number):
        return None
    return int(number) if kind is int else number


def _raw(source: Any, name: str, k: int | None) -> Any:
    attribute, factor = SOLVER_UNITS.get(name, (name, 1.0))
    value = getattr(source, attribute, None)
    if value is None:
        return None
    value = value if k is None else value[k]
    return value * factor if factor != 1.0 else value


def of_frame(source: Any, k: int | None = None, names: tuple[str, ...] | None = None) -> dict[str, Any]:
    """The record of one frame: of a ``LiveFix`` (``k`` None) or of frame ``k`` of a ``TrackResult``.
    ``names``: a part of the record (default all). A quantity the source lacks is left out."""
    record = {}
    for name in names or BY_NAME:
        value = _raw(source, name, k)
        if value is not None or BY_NAME[name].kind is str:
            record[name] = typed(name, value)
    return record


def columns(result: Any) -> dict[str, np.ndarray]:
    """The record of every frame of a ``TrackResult`` as columns (the CSV's): flags 0/1, counts as
    integers, figures as floats (NaN where they do not exist), reasons as strings."""
    import numpy as np  # not at the top: graytrack.wire (the client's models) imports this table without numpy

    out = {}
    for quantity in QUANTITIES:
        value = _raw(result, quantity.name, None)
        if value is None:
            continue
        value = np.asarray(value)
        out[quantity.name] = value.astype(int) if quantity.kind is bool else value
    return out
