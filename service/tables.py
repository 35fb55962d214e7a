"""Plain CSV output of per-frame columns (no pandas: the daemon's install stays small)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from graytrack.core.files import open_atomic


def write_csv(path: str | os.PathLike[str], columns: dict[str, np.ndarray]) -> Path:
    """Write equal-length columns with a header, atomically (never a half-written table)."""
    path = Path(path)
    table = np.column_stack([np.asarray(values, dtype=np.float64) for values in columns.values()])
    with open_atomic(path) as fh:
        np.savetxt(fh, table, delimiter=",", header=",".join(columns), comments="", fmt="%.9g")
    return path
