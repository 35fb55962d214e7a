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
    arrays = [np.asarray(column) for column in columns.values()]
    text = [values.dtype.kind in "US" for values in arrays]
    # one %-format a row over plain Python values: the same text as formatting each cell alone
    row_format = ",".join("%s" if is_text else "%.9g" for is_text in text)
    cells = [values.astype(str).tolist() if is_text else values.astype(np.float64).tolist()
             for values, is_text in zip(arrays, text)]
    rows = [row_format % row for row in zip(*cells)]
    with open_atomic(path) as fh:
        fh.write((",".join(columns) + "\n").encode())
        if rows:
            fh.write(("\n".join(rows) + "\n").encode())
    return path
