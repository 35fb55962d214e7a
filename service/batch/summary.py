"""``summary.csv`` of a batch: one row per recording, the same columns whatever the work.

Numbers are written with 6 significant digits, so the same work gives the same text on any
worker; columns a kind of work does not produce stay empty.
"""

from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path
from typing import Any, Iterable

from graytrack.core.files import write_atomic

MARKER = "batch.json"  # OUT/<name>/batch.json: written last, so its presence means the outputs are complete
SUMMARY = "summary.csv"
COLUMNS = (
    "path", "name", "rig", "calibrated_at", "frames", "rows_x_pixels", "model", "rmse_gray",
    "error_std_before_um", "crlb_before_um", "error_std_after_um", "crlb_after_um", "effects",
    "tau_w_mm", "tau_w_u_mm", "alpha_d_mm", "alpha_d_u_mm", "noise_gray", "locked", "lock_events",
    "seconds", "status", "reason", "notes",
)
DIGITS = {"seconds": 3}


def _text(key: str, value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, (int,)) or (hasattr(value, "dtype") and value.dtype.kind in "iu"):
        return str(int(value))
    if isinstance(value, float) or hasattr(value, "dtype"):
        value = float(value)
        return "" if not math.isfinite(value) else f"{value:.{DIGITS.get(key, 6)}g}"
    return str(value).replace("\n", " ")


def format_row(values: dict[str, Any]) -> dict[str, str]:
    """Every column as text (missing ones empty); unknown keys are dropped."""
    return {key: _text(key, values.get(key)) for key in COLUMNS}


def write_summary(path: str | os.PathLike[str], rows: Iterable[dict[str, str]]) -> Path:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({key: row.get(key, "") for key in COLUMNS})
    return write_atomic(path, buffer.getvalue())


def read_summary(path: str | os.PathLike[str]) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))
