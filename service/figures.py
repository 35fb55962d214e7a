"""Numbers as reports show them: every figure may be missing, and a missing one reads "—".

A report is written after the work is done, from whatever the work produced: a model that placed
none of the held-out frames has no error std, a tracker that lost every frame has no bound, a
recording without a reference has no readout step. Those are null in report.json (JSON has no
NaN) and "—" on a page; a report must never fail, or show "nan" or "None", because one figure
does not exist. The command line shows the same with ASCII ("n/a").
"""

from __future__ import annotations

import math
import re
from typing import Any

MISSING = "—"


def is_number(value: Any) -> bool:
    """A finite real number (bools are flags, not figures)."""
    if isinstance(value, bool) or value is None:
        return False
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


def positive(value: Any) -> bool:
    """A figure, and above zero (a readout step of 0 means "none found", not a step)."""
    return is_number(value) and float(value) > 0.0


def shown(value: Any, digits: int, unit: str = "", missing: str = MISSING) -> str:
    """``value`` with ``digits`` decimals (and `` unit``), or ``missing`` when it is null, NaN or infinite."""
    if not is_number(value):
        return missing
    text = f"{float(value):.{digits}f}"
    if float(text) == 0.0:
        text = text.lstrip("-")  # −0.0004 shown to three decimals is 0.000, not −0.000
    return f"{text} {unit}" if unit else text



GEOMETRY = re.compile(r"; τ=[^;)]*, α·d=[^;)]*\)$")


def structure(description: object) -> str:
    """A model's description without its geometry: τ and α·d are stated once, of the model written
    (model.json), and not again for each stage of its making (fitted on fewer frames, they differ)."""
    return GEOMETRY.sub(")", str(description or ""))
