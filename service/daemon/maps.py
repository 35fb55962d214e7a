"""The learned maps as the page draws them (``GET /api/maps``): the sensor's map along the pixels (each
sample's gain and offset with their σ, one row or the rows averaged), the print's map along the target (each
touched place's reflectance with its σ, likewise) and the print's texture of today's tracker along the target
(each mark's stretch, depth and its σ).

Made on request from the newest snapshot the frame loop took for the model of record (map_store.py), never
from the live map: a page asks every few seconds, the frame loop is never held for it. The status carries
the counts and a few marks; the arrays are here, a few kB a row (the status stays small at every poll).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from graytrack.service.daemon.acquisition import Acquisition
from graytrack.service.daemon.map_store import MapSnapshot


def _latest(acquisition: Acquisition | None, name: str) -> MapSnapshot | None:
    snapshotter = acquisition.snapshots.get(name) if acquisition is not None else None
    return snapshotter.latest if snapshotter is not None else None


def sensor_map(snapshot: MapSnapshot | None, row: int | None) -> dict[str, Any] | None:
    """The sensor's map along the pixels of ``row`` (None: the rows averaged, each σ that of the mean of the
    rows' independent pairs); untouched samples are as calibrated (gain 1, offset 0, σ 0)."""
    if snapshot is None:
        return None
    state = snapshot.state
    rows, pixels = int(state["rows"]), int(state["pixels"])
    if row is not None and not 0 <= row < rows:
        raise IndexError(f"row {row} is outside the sensor map's {rows} row(s)")
    where = np.asarray(state["touched"], dtype=np.int64)
    f, e = np.zeros(rows * pixels), np.zeros(rows * pixels)
    sff, see = np.zeros(rows * pixels), np.zeros(rows * pixels)
    touched, learned = np.zeros(rows * pixels, dtype=bool), np.zeros(rows * pixels, dtype=bool)
    f[where], e[where], sff[where], see[where] = state["f"], state["e"], state["sff"], state["see"]
    touched[where], learned[where] = True, np.asarray(state["learned"], dtype=bool)
    shown = slice(None) if row is None else slice(row, row + 1)
    f, e, sff, see = (a.reshape(rows, pixels)[shown] for a in (f, e, sff, see))
    touched, learned = touched.reshape(rows, pixels)[shown], learned.reshape(rows, pixels)[shown]
    count = f.shape[0]
    return {"calibration": snapshot.calibration, "rows": rows, "row": row, "pixels": pixels,
            "gain": (1.0 + f.mean(axis=0)).round(4).tolist(),
            "gain_sigma": (np.sqrt(sff.sum(axis=0)) / count).round(4).tolist(),
            "offset_gray": e.mean(axis=0).round(3).tolist(),
            "offset_sigma_gray": (np.sqrt(see.sum(axis=0)) / count).round(3).tolist(),
            "touched": np.flatnonzero(touched.any(axis=0)).tolist(),
            "learned": np.flatnonzero(learned.any(axis=0)).tolist(),
            "marks": [mark for mark in state["marks"] if row is None or mark["row"] == row]}


def print_map(snapshot: MapSnapshot | None, row: int | None) -> dict[str, Any] | None:
    """The print's map along the target: each place something landed on in ``row`` (None: in any row, its
    reflectance the rows' mean and its σ that of the mean of the rows' independent nodes), with the reflectance
    ``1 + f`` and σ; untouched places are as calibrated (1, σ 0) and are not listed."""
    if snapshot is None:
        return None
    state = snapshot.state
    rows, nodes, step, origin = int(state["rows"]), int(state["nodes"]), float(state["node_mm"]), \
        float(state["origin_mm"])
    if row is not None and not 0 <= row < rows:
        raise IndexError(f"row {row} is outside the print map's {rows} row(s)")
    where = np.asarray(state["touched"], dtype=np.int64)
    f, s = np.zeros(rows * nodes), np.zeros(rows * nodes)
    touched, learned = np.zeros(rows * nodes, dtype=bool), np.zeros(rows * nodes, dtype=bool)
    f[where], s[where], touched[where] = state["f"], state["s"], True
    learned[where] = np.asarray(state["learned"], dtype=bool)
    shown = slice(None) if row is None else slice(row, row + 1)
    f, s = f.reshape(rows, nodes)[shown], s.reshape(rows, nodes)[shown]
    touched, learned = touched.reshape(rows, nodes)[shown], learned.reshape(rows, nodes)[shown]
    count = f.shape[0]
    columns = np.flatnonzero(touched.any(axis=0))
    return {"calibration": snapshot.calibration, "rows": rows, "row": row, "node_mm": step,
            "x_mm": (origin + columns * step).round(5).tolist(),
            "reflectance": (1.0 + f[:, columns].mean(axis=0)).round(4).tolist(),
            "reflectance_sigma": (np.sqrt(s[:, columns].sum(axis=0)) / count).round(4).tolist(),
            "learned": learned[:, columns].any(axis=0).tolist(),
            "marks": [mark for mark in state["marks"] if row is None or mark["row"] == row]}


def texture(snapshot: MapSnapshot | None) -> dict[str, Any] | None:
    """The print's texture along the target: each learned mark's stretch, depth and its σ."""
    if snapshot is None:
        return None
    keys = ("x_mm", "from_mm", "to_mm", "depth", "depth_sigma")
    return {"calibration": snapshot.calibration,
            "marks": [{key: mark["describe"][key] for key in keys} for mark in snapshot.state["marks"]]}


def maps(acquisition: Acquisition | None, stroke_mm: tuple[float, float] | None, row: int | None) -> dict[str, Any]:
    """The maps (each None when the engine keeps none, or before its first snapshot) and the target's stroke."""
    return {"sensor_map": sensor_map(_latest(acquisition, "sensor_map"), row),
            "print_map": print_map(_latest(acquisition, "print_map"), row),
            "texture": texture(_latest(acquisition, "texture")),
            "stroke_mm": list(stroke_mm) if stroke_mm is not None else None}
