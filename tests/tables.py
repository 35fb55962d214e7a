"""Reading the track command's CSV in tests as a user's script would: by column name, numbers as
floats, the text columns (``stale_reason``) as text."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

TEXT_COLUMNS = {"stale_reason"}


def read_columns(path: str | Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    names = list(rows[0]) if rows else Path(path).read_text().splitlines()[0].split(",")
    return {name: np.array([row[name] for row in rows], dtype=str if name in TEXT_COLUMNS else np.float64)
            for name in names}
