"""The recording file: one run of the rig as one ``.npz`` (DESIGN.md, "recording files").

A recording is what every other part trades in (the virtual rig writes it, calibration and the
closed loop read it, the daemon stores it), so the reader is strict: anything malformed is
refused with a message that names the offending key, and nothing downstream ever sees a
half-valid array.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from graytrack.core.errors import GraytrackError

FRAME_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.float32), np.dtype(np.float64))


class RecordingError(GraytrackError):
    """A recording file or array set that does not follow the contract."""


@dataclass
class Recording:
    """Frames of a pixel line (or strip), their times and the grating readout.

    ``frames`` is ``(K, n)`` or ``(K, R, n)``; the last axis is the pixel index u, increasing with
    the target coordinate. ``reference`` holds the grating position in mm, NaN where there is none.
    """

    frames: np.ndarray
    t: np.ndarray
    reference: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.frames = np.asarray(self.frames)
        self.t = np.asarray(self.t, dtype=np.float64)
        self.reference = np.asarray(self.reference, dtype=np.float64)
        validate(self)

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def n_rows(self) -> int:
        return 1 if self.frames.ndim == 2 else int(self.frames.shape[1])

    @property
    def n_pixels(self) -> int:
        return int(self.frames.shape[-1])

    def strip(self) -> np.ndarray:
        """Frames as float64 ``(K, R, n)``, whatever their stored layout and dtype."""
        frames = self.frames.astype(np.float64)
        return frames[:, None, :] if frames.ndim == 2 else frames

    def subset(self, index: np.ndarray | slice) -> "Recording":
        """The same recording restricted to some frames (for hold-out splits)."""
        return Recording(self.frames[index], self.t[index], self.reference[index], dict(self.meta))

    def has_reference(self) -> bool:
        return bool(np.isfinite(self.reference).any())


def validate(rec: Recording) -> None:
    """Raise :class:`RecordingError` naming the first key that breaks the contract."""
    frames = rec.frames
    if frames.dtype not in FRAME_DTYPES:
        raise RecordingError(f"frames: dtype {frames.dtype} is not one of uint8, uint16, float32, float64")
    if frames.ndim not in (2, 3):
        raise RecordingError(f"frames: expected shape (K, n) or (K, R, n), got {frames.shape}")
    n_frames = frames.shape[0]
    if n_frames == 0 or frames.shape[-1] < 2 or (frames.ndim == 3 and frames.shape[1] == 0):
        raise RecordingError(f"frames: empty shape {frames.shape}")
    if frames.dtype.kind == "f":
        bad = ~np.isfinite(frames).reshape(n_frames, -1).all(axis=1)
        if bad.any():
            raise RecordingError(
                f"frames: {int(bad.sum())} frame(s) hold NaN or infinite gray values (first at frame {int(np.argmax(bad))})"
            )
    for key, values in (("t", rec.t), ("reference", rec.reference)):
        if values.shape != (n_frames,):
            raise RecordingError(f"{key}: expected shape ({n_frames},) to match frames, got {values.shape}")
    if not np.isfinite(rec.t).all():
        raise RecordingError("t: holds NaN or infinite times")
    if np.isinf(rec.reference).any():
        raise RecordingError("reference: holds infinite values (use NaN for 'no reading')")
    if not isinstance(rec.meta, dict):
        raise RecordingError("meta: must be a JSON object")
    for key in ("pixel_pitch_mm", "period_mm"):
        if key in rec.meta:
            value = rec.meta[key]
            if not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
                raise RecordingError(f"meta: {key} must be a positive number, got {value!r}")


def save(rec: Recording, path: str | os.PathLike[str]) -> Path:
    """Write atomically: a crash mid-write never leaves a truncated file under the final name."""
    validate(rec)
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        np.savez_compressed(
            fh,
            frames=rec.frames,
            t=rec.t,
            reference=rec.reference,
            meta=np.array(json.dumps(rec.meta, sort_keys=True)),
        )
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path


def load(path: str | os.PathLike[str]) -> Recording:
    """Read and validate a recording; unknown keys are ignored."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    with open(path, "rb") as fh:
        if fh.read(4) != b"PK\x03\x04":
            raise RecordingError(f"{path}: not an .npz recording (no zip archive header)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            missing = [key for key in ("frames", "t", "reference") if key not in archive.files]
            if missing:
                raise RecordingError(f"{path}: missing key {missing[0]!r}")
            arrays = {key: archive[key] for key in ("frames", "t", "reference")}
            meta_raw = archive["meta"] if "meta" in archive.files else None
    except RecordingError:
        raise
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
        raise RecordingError(f"{path}: not a readable .npz recording ({exc})") from None
    meta = _parse_meta(meta_raw, path)
    for key in ("t", "reference"):
        if arrays[key].dtype.kind not in "fiu":
            raise RecordingError(f"{path}: {key}: expected float64, got {arrays[key].dtype}")
    try:
        return Recording(arrays["frames"], arrays["t"], arrays["reference"], meta)
    except RecordingError as exc:
        raise RecordingError(f"{path}: {exc}") from None


def _parse_meta(raw: np.ndarray | None, path: Path) -> dict[str, Any]:
    if raw is None:
        return {}
    if raw.shape != () or raw.dtype.kind not in "US":
        raise RecordingError(f"{path}: meta: expected a 0-d string holding JSON, got {raw.dtype} {raw.shape}")
    try:
        meta = json.loads(str(raw))
    except json.JSONDecodeError as exc:
        raise RecordingError(f"{path}: meta: not valid JSON ({exc.msg})") from None
    if not isinstance(meta, dict):
        raise RecordingError(f"{path}: meta: must be a JSON object, got {type(meta).__name__}")
    return meta
