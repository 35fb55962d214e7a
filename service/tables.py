"""Plain CSV output of per-frame columns (no pandas: the daemon's install stays small)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from graytrack.core.files import open_atomic


def write_csv(path: str | os.PathLike[str], columns: dict[str, np.ndarray]) -> Path:
    """Write equal-length columns with a header, atomically (never a half-written table). Numbers
    are written to 9 significant digits; text columns (a stale reason) as they are."""
    path = Path(path)
    cells = [values.astype(str) if (values := np.asarray(column)).dtype.kind in "US"
             else np.char.mod("%.9g", values.astype(np.float64)) for column in columns.values()]
    rows = cells[0].astype(object)
    for column in cells[1:]:
        rows = rows + "," + column.astype(object)
    with open_atomic(path) as fh:
        fh.write((",".join(columns) + "\n").encode())
        if rows.size:
            fh.write(("\n".join(rows) + "\n").encode())
    return path
