"""``history.html``: each rig's calibrations against time, self-contained like ``report.html``
(plots embedded as PNG data: it is read on rigs without network and mailed around as it is)."""

from __future__ import annotations

import html
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from graytrack.core.files import write_atomic  # noqa: E402
from graytrack.service.batch.history import (QUANTITIES, Z_LIMIT, Change, DriftQuantity, RigCalibration,  # noqa: E402
                                             changes, effect_changes, series)
from graytrack.service.report_kit import image, page, png, table  # noqa: E402


def figure(rigs: dict[str, list[RigCalibration]], found: list[Change]) -> str:
    """One panel per quantity (value ± its uncertainty per rig), and the effects found."""
    fig, axes = plt.subplots(len(QUANTITIES) + 1, 1, figsize=(11, 2.3 * (len(QUANTITIES) + 1)), sharex=True)
    effect_names = sorted({name for cals in rigs.values() for c in cals for name in c.effects})
    for index, (rig, cals) in enumerate(rigs.items()):
        colour = f"C{index % 10}"
        for ax, q in zip(axes, QUANTITIES):
            when, values, errors = series(cals, q.key, q.scale)
            ax.errorbar(when, values, yerr=np.where(np.isfinite(errors), errors, 0.0), fmt="o-", ms=4, capsize=3,
                        color=colour, label=rig)
        for change in (c for c in found if c.rig == rig):
            ax = axes[QUANTITIES.index(change.quantity)]
            ax.plot([change.at.when], [change.at.values[change.quantity.key] * change.quantity.scale], "o", ms=12,
                    mfc="none", mec="red", mew=2)
        for c in cals:
            rows = [effect_names.index(name) for name in c.effects]
            axes[-1].plot([c.when] * len(rows), rows, "s", color=colour, ms=6)
    for ax, q in zip(axes, QUANTITIES):
        ax.set_ylabel(f"{q.label}\n({q.unit})", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_yticks(range(len(effect_names)), effect_names, fontsize=8)
    axes[-1].set_ylim(-0.7, max(len(effect_names), 1) - 0.3)
    axes[-1].set_ylabel("effects found", fontsize=9)
    axes[-1].set_xlabel("calibration time (UTC)")
    fig.autofmt_xdate()
    return png(fig)


def _value(c: RigCalibration, q: DriftQuantity) -> str:
    """A quantity of one calibration, with its standard uncertainty when known."""
    uncertainty = c.uncertainty[q.key] * q.scale
    return f"{c.values[q.key] * q.scale:.6g}" + (f" ± {uncertainty:.2g}" if np.isfinite(uncertainty) else "")


def _table(rigs: dict[str, list[RigCalibration]]) -> str:
    header = ["rig", "calibrated (UTC)", *(f"{q.label} ({q.unit})" for q in QUANTITIES), "effects"]
    rows = [[rig, f"{c.when:%Y-%m-%d %H:%M:%S}", *(_value(c, q) for q in QUANTITIES), ", ".join(c.effects) or "—"]
            for rig, cals in rigs.items() for c in cals]
    return table(header, rows)


def render(rigs: dict[str, list[RigCalibration]]) -> tuple[str, list[Change]]:
    found = [change for cals in rigs.values() for change in changes(cals)]
    effects = [line for cals in rigs.values() for line in effect_changes(cals)]
    items = "".join(f"<li class=flag>{html.escape(change.text())}</li>" for change in found)
    count = sum(len(cals) for cals in rigs.values())
    body = f"""<p>{count} calibration(s) of {len(rigs)} rig(s). A value is pointed out when it moved from the rig's
previous calibration, or drifted from the level of its last change (at first: its first calibration) by more than
{Z_LIMIT:g} times the combined standard uncertainty (τ_w and α·d: spread of interleaved refits of each sweep; σ and
the held-out error: σ/√(2n) of their sample counts).</p>
<h2>Changes beyond the calibrations' uncertainty</h2><ul id="changes">{items or '<li>none</li>'}</ul>
<h2>Effects found by the closed loop</h2><ul>{''.join(f'<li>{html.escape(line)}</li>' for line in effects)
                                           or '<li>no change in the effects found</li>'}</ul>
{image("Against calibration time", figure(rigs, found))}
<h2>Calibrations</h2>{_table(rigs)}"""
    return page("graytrack history", body), found


def write_history(rigs: dict[str, list[RigCalibration]], path: str | os.PathLike[str]) -> tuple[Path, list[Change]]:
    text, found = render(rigs)
    return write_atomic(path, text), found
