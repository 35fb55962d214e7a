"""The CSV writer's bytes are a contract: formatting a column's distinct values once must give the
same text as formatting every cell (``"%.9g"`` of the float, text as it is)."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.service.tables import write_csv


def reference_text(columns: dict[str, np.ndarray]) -> bytes:
    """The table as one %-format per row over plain Python values (the writer's former way)."""
    arrays = [np.asarray(column) for column in columns.values()]
    text = [values.dtype.kind in "US" for values in arrays]
    row_format = ",".join("%s" if is_text else "%.9g" for is_text in text)
    cells = [values.astype(str).tolist() if is_text else values.astype(np.float64).tolist()
             for values, is_text in zip(arrays, text)]
    rows = [row_format % row for row in zip(*cells)]
    return ((",".join(columns) + "\n") + ("\n".join(rows) + "\n" if rows else "")).encode()


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 1000])
def test_csv_bytes_match_per_cell_formatting(tmp_path, n):
    rng = np.random.default_rng(n)
    columns = {
        "t": np.arange(n) * 1e-3, "x_mm": rng.normal(size=n) * 1e3, "locked": (rng.random(n) > 0.5).astype(int),
        "flag": rng.random(n) > 0.5, "count": rng.integers(0, 3, n), "none": np.full(n, np.nan),
        "zero": np.where(rng.random(n) > 0.5, -0.0, 0.0), "inf": np.where(rng.random(n) > 0.5, np.inf, -np.inf),
        "reason": np.array(["", "light"] * (n // 2) + [""] * (n % 2), dtype="<U10"),
        "single": rng.random(n).astype(np.float32), "huge": rng.normal(size=n) * 1e300,
        "subnormal": rng.normal(size=n) * 1e-310, "few": rng.choice([1.0, 0.9999999999, 1.5e-7, np.nan], n),
    }
    path = write_csv(tmp_path / "t.csv", columns)
    assert path.read_bytes() == reference_text(columns)
