"""From the command line's PATHS to the list of recordings a batch works on.

A path is a recording, a folder or a glob. A daemon's data directory (a folder with
``calibrations/``) contributes its ``calibrations/*/recording.npz``; any other folder contributes
every ``.npz`` below it. Each recording gets a name that is stable across runs (resume finds its
outputs under ``OUT/<name>/`` again) and, where the layout tells, the rig and calibration time
its figures are plotted against in ``graytrack history``.
"""

from __future__ import annotations

import glob
import re
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Iterable

from graytrack.service.errors import CliError

CALIBRATION_ID = re.compile(r"^(\d{8}T\d{6})(\d{6})Z$")
SAFE_NAME = re.compile(r"[^A-Za-z0-9._-]+")


@dataclass(frozen=True)
class Source:
    """One recording of a batch: where it is, its output folder name, and what the layout says."""

    path: Path
    name: str
    rig: str = ""            # data directory name, when the recording is a daemon's calibration
    calibrated_at: str = ""  # ISO 8601 UTC from the calibration id, when there is one


def calibration_time(calibration_id: str) -> str:
    """``20261122T053131123456Z`` → ``2026-11-22T05:31:31.123456Z`` ('' when not an id)."""
    match = CALIBRATION_ID.match(calibration_id)
    if not match:
        return ""
    stamp = datetime.strptime(match.group(1) + match.group(2), "%Y%m%dT%H%M%S%f").replace(tzinfo=timezone.utc)
    return stamp.isoformat().replace("+00:00", "Z")


def _expand(pattern: str) -> list[Path]:
    path = Path(pattern)
    if path.exists():
        return [path]
    matches = sorted(glob.glob(pattern, recursive=True))
    if not matches:
        raise CliError(f"{pattern}: no such file, folder or matching glob")
    return [Path(match) for match in matches]


def _recordings_in(folder: Path) -> list[Path]:
    calibrations = folder / "calibrations"
    if calibrations.is_dir():
        return sorted(calibrations.glob("*/recording.npz"))
    return sorted(p for p in folder.rglob("*.npz") if not any(part.startswith(".") for part in p.parts))


def _source(path: Path) -> Source:
    calibration = path.parent
    if path.name == "recording.npz" and calibration.parent.name == "calibrations":
        rig = calibration.parent.parent.resolve().name
        return Source(path, f"{rig}-{calibration.name}", rig, calibration_time(calibration.name))
    return Source(path, path.stem)


def _unique(sources: list[Source]) -> list[Source]:
    """Clashing names get their parent folder's name in front, then a counter."""
    seen: dict[str, int] = {}
    out = []
    for source in sources:
        name = SAFE_NAME.sub("_", source.name)
        if name in seen:
            name = SAFE_NAME.sub("_", f"{source.path.parent.name}-{source.name}")
        while name in seen:
            seen[name] += 1
            name = f"{name}-{seen[name]}"
        seen[name] = 1
        out.append(Source(source.path, name, source.rig, source.calibrated_at))
    return out


def discover(patterns: Iterable[str]) -> list[Source]:
    """Every recording the PATHS name, each once, in a stable order."""
    found: dict[Path, Path] = {}
    for pattern in patterns:
        for path in _expand(pattern):
            for recording in (_recordings_in(path) if path.is_dir() else [path]):
                found.setdefault(recording.resolve(), recording)
    if not found:
        raise CliError("no recordings found in " + ", ".join(patterns))
    return _unique([_source(path) for path in found.values()])
