"""Drift over months: each rig's calibrations in time order, and the changes beyond their uncertainty.

Input is what ``graytrack batch calibrate|diagnose`` writes: ``summary.csv`` rows with the rig,
the calibration time, τ_w and α·d with their uncertainty (interleaved refits, core/geometry_spread),
the noise σ, the held-out error and the effects the closed loop found. A value is pointed out when
it moved further from the rig's previous calibration, or from the level of its last change (or
first calibration: slow drift hides between neighbours), than ``Z_LIMIT`` combined standard
uncertainties.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Iterable

import numpy as np

from graytrack.service.batch.summary import SUMMARY, read_summary
from graytrack.service.errors import CliError

Z_LIMIT = 4.0  # with uncertainties estimated from a few refits, z has heavier tails than a normal


@dataclass(frozen=True)
class DriftQuantity:
    key: str
    label: str
    unit: str
    scale: float = 1.0  # shown value = stored value × scale


QUANTITIES = (
    DriftQuantity("tau_w_mm", "target period τ_w", "µm", 1e3),
    DriftQuantity("alpha_d_mm", "pixel footprint α·d", "nm", 1e6),
    DriftQuantity("noise_gray", "noise σ", "gray"),
    DriftQuantity("error_std_after_um", "held-out error std", "µm"),
)


@dataclass(frozen=True)
class RigCalibration:
    rig: str
    when: datetime
    path: str
    values: dict[str, float]        # quantity key → value (NaN when the row has none)
    uncertainty: dict[str, float]   # quantity key → standard uncertainty (NaN when unknown)
    effects: tuple[str, ...]


@dataclass(frozen=True)
class Change:
    rig: str
    quantity: DriftQuantity
    since: RigCalibration
    at: RigCalibration
    z: float
    against: str  # "previous" (a step) or "baseline" (drift accumulated since ``since``)

    def text(self) -> str:
        q = self.quantity
        delta = (self.at.values[q.key] - self.since.values[q.key]) * q.scale
        how = ("a step from the previous calibration" if self.against == "previous"
               else "a drift over several calibrations")
        return (f"{self.rig}: {q.label} changed by {delta:+.4g} {q.unit} from {self.since.when:%Y-%m-%d %H:%M} "
                f"to {self.at.when:%Y-%m-%d %H:%M} ({self.z:.1f}× the combined uncertainty; {how})")


def _number(text: str | None) -> float:
    try:
        return float(text) if text not in (None, "") else math.nan
    except ValueError:
        return math.nan


def _time(text: str) -> datetime | None:
    try:
        return datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None


def statistical_uncertainty(key: str, value: float, row: dict[str, str]) -> float:
    """Uncertainty of a standard deviation estimated from n samples: σ/√(2n).

    The noise σ comes from every pixel of every frame, the held-out error from about half of the
    frames (the interleaved hold-out), so the sample counts follow from the row.
    """
    frames = _number(row.get("frames"))
    rows, _, pixels = (row.get("rows_x_pixels") or "").partition("x")
    samples = {"noise_gray": frames * _number(rows) * _number(pixels), "error_std_after_um": frames / 2.0}[key]
    return value / math.sqrt(2.0 * samples) if samples > 0 else math.nan


def calibration_of(row: dict[str, str]) -> RigCalibration | None:
    when = _time(row.get("calibrated_at", ""))
    if row.get("status") != "ok" or when is None:
        return None
    values = {q.key: _number(row.get(q.key)) for q in QUANTITIES}
    uncertainty = {"tau_w_mm": _number(row.get("tau_w_u_mm")), "alpha_d_mm": _number(row.get("alpha_d_u_mm"))}
    for key in ("noise_gray", "error_std_after_um"):
        uncertainty[key] = statistical_uncertainty(key, values[key], row)
    effects = tuple(name for name in (row.get("effects") or "").split(";") if name)
    return RigCalibration(row.get("rig") or "rig", when, row.get("path", ""), values, uncertainty, effects)


def load_calibrations(folders: Iterable[str | Path]) -> dict[str, list[RigCalibration]]:
    """Every usable row of the batches' summaries, per rig, in time order (a recording once)."""
    seen: dict[str, RigCalibration] = {}
    for folder in folders:
        folder = Path(folder)
        summary = folder if folder.is_file() else folder / SUMMARY
        if not summary.is_file():
            if (folder / "calibrations").is_dir():
                raise CliError(f"{folder} is a daemon's data directory: run `graytrack batch diagnose {folder} "
                               f"--out OUT` first, then `graytrack history OUT`")
            raise CliError(f"{folder}: no {SUMMARY} (the output folder of `graytrack batch calibrate|diagnose`)")
        for row in read_summary(summary):
            calibration = calibration_of(row)
            if calibration is not None:
                seen.setdefault(calibration.path, calibration)
    rigs: dict[str, list[RigCalibration]] = {}
    for calibration in sorted(seen.values(), key=lambda c: (c.rig, c.when)):
        rigs.setdefault(calibration.rig, []).append(calibration)
    if not rigs:
        raise CliError("no successful calibration with a time in " + ", ".join(str(f) for f in folders))
    return rigs


def _z(a: RigCalibration, b: RigCalibration, key: str) -> float:
    combined = math.hypot(a.uncertainty[key], b.uncertainty[key])
    delta = abs(b.values[key] - a.values[key])
    return delta / combined if combined > 0 else math.nan


def changes(calibrations: list[RigCalibration], z_limit: float = Z_LIMIT) -> list[Change]:
    """Changes of one rig beyond ``z_limit`` combined uncertainties: a step from one calibration
    to the next, or a slow drift accumulated since the last change (or the first calibration)."""
    found: list[Change] = []
    for q in QUANTITIES:
        baseline = calibrations[0] if calibrations else None
        for before, after in zip(calibrations, calibrations[1:]):
            step, drift = _z(before, after, q.key), _z(baseline, after, q.key)
            if step > z_limit:
                found.append(Change(after.rig, q, before, after, step, "previous"))
            elif baseline is not before and drift > z_limit:
                found.append(Change(after.rig, q, baseline, after, drift, "baseline"))
            else:
                continue
            baseline = after  # the new level is what later calibrations are held against
    return sorted(found, key=lambda change: change.at.when)


def effect_changes(calibrations: list[RigCalibration]) -> list[str]:
    """Effects the closed loop started or stopped finding, calibration to calibration."""
    lines = []
    for before, after in zip(calibrations, calibrations[1:]):
        gained, lost = set(after.effects) - set(before.effects), set(before.effects) - set(after.effects)
        if gained or lost:
            parts = ([f"now finds {', '.join(sorted(gained))}"] if gained else []) + \
                    ([f"no longer finds {', '.join(sorted(lost))}"] if lost else [])
            lines.append(f"{after.rig}, {after.when:%Y-%m-%d %H:%M}: the closed loop {' and '.join(parts)}")
    return lines


def series(calibrations: list[RigCalibration], key: str,
           scale: float = 1.0) -> tuple[list[datetime], np.ndarray, np.ndarray]:
    when = [c.when for c in calibrations]
    values = np.array([c.values[key] for c in calibrations]) * scale
    errors = np.array([c.uncertainty[key] for c in calibrations]) * scale
    return when, values, errors
