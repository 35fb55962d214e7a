"""Plain CSV output of per-frame columns (no pandas: the daemon's install stays small)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from graytrack.core.files import open_atomic

NUMBER_FORMAT = "%.9g"
# A column with at most one distinct value in this many rows is formatted once per distinct value
# (flags, counts, a light at 1 and 0, NaN where a figure does not exist: most of a track's columns).
FEW_DISTINCT = 4


def write_csv(path: str | os.PathLike[str], columns: dict[str, np.ndarray]) -> Path:
    """Write equal-length columns with a header, atomically (never a half-written table). Numbers
    are written to 9 significant digits; text columns (a stale reason) as they are."""
    path = Path(path)
    cells = [column_text(np.asarray(column)) for column in columns.values()]
    with open_atomic(path) as fh:
        fh.write((",".join(columns) + "\n").encode())
        if cells and cells[0]:
            fh.write(("\n".join(map(",".join, zip(*cells))) + "\n").encode())
    return path


def column_text(values: np.ndarray) -> list[str]:
    """Each cell of one column as the CSV writes it: text as it is, a number as ``"%.9g" %
    float(value)`` (a flag 0/1, a count as its integer, NaN as ``nan``). A column of few distinct
    values formats each of them once (told apart by their bits: ``-0`` stays ``-0``)."""
    if values.dtype.kind in "US":
        return values.astype(str).tolist()
    numbers = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    if numbers.size >= 2 * FEW_DISTINCT:
        distinct, where = np.unique(numbers.view(np.int64), return_inverse=True)
        if distinct.size * FEW_DISTINCT <= numbers.size:
            texts = np.array([NUMBER_FORMAT % value for value in distinct.view(np.float64).tolist()], dtype=object)
            return texts[where.reshape(-1)].tolist()
    return list(map(NUMBER_FORMAT.__mod__, numbers.tolist()))
