"""Reports as JSON can carry them: a figure that does not exist is null, never NaN.

``json.dumps(..., allow_nan=False)`` (what the report writers use, so that every reader can parse
the file) refuses NaN and infinity; a report built from a run where a figure could not be measured
(no frame placed, no bound) must still be written, with that figure null.
"""

from __future__ import annotations

import math
from typing import Any


def finite_or_none(value: Any) -> Any:
    """``value`` with every non-finite float, at any depth of dicts, lists and tuples, made None
    (numpy scalars become Python numbers on the way)."""
    if isinstance(value, dict):
        return {key: finite_or_none(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(item) for item in value]
    if hasattr(value, "dtype") and getattr(value, "shape", None) == ():  # a numpy scalar
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
