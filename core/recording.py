"""The recording file: one run of the rig as one ``.npz`` (docs/contracts.md, "recording files").

A recording is what every other part trades in (the virtual rig writes it, calibration and the
closed loop read it, the daemon stores it), so the reader is strict: anything malformed is
refused with a message that names the offending key, and nothing downstream ever sees a
half-valid array. A file is checked against what it declares before anything is read: the zip
directory's sizes and each array's ``.npy`` header must describe arrays that fit the memory
budget (:func:`memory_budget_bytes`), so a hostile file (a header claiming 10¹² frames, a small
zip inflating to gigabytes) is refused in one line instead of exhausting memory.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import threading
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from graytrack.core.errors import GraytrackError
from graytrack.core.files import open_atomic

FRAME_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.float32), np.dtype(np.float64))
ARRAY_KEYS = ("frames", "t", "reference")
MAX_ABS_REFERENCE_MM = 1e6  # a kilometre: beyond it a "position" is a unit or scaling mistake
MAX_ABS_GRAY = 1e9  # float frames beyond this are not gray levels (and overflow squared sums)
MAX_META_BYTES = 1 << 20
BUDGET_ENV = "GRAYTRACK_MEMORY_BUDGET_MB"
# A member is deflated only where that pays: the frames of a noisy float camera deflate by ~12 % (the low bits of
# noise do not repeat) and inflate at ~350 MB/s, which for a 16-row strip was half of `graytrack track`'s time;
# an integer camera's frames deflate by a third to a half and are deflated as before.
DEFLATE_WORTH = 0.8  # 1 (share of the bytes): deflated to more than this, a member is stored as it is
DEFLATE_LEVEL = 6  # zlib's default, the level numpy's savez_compressed writes with
DEFLATE_SAMPLE, DEFLATE_SAMPLES = 4096, 32  # bytes a sample, samples spread over an array to judge it by


def memory_budget_bytes() -> int:
    """How much a recording may need once loaded: a quarter of this machine's memory
    (``GRAYTRACK_MEMORY_BUDGET_MB`` overrides), since the tools work on float64 copies."""
    override = os.environ.get(BUDGET_ENV)
    if override:
        try:
            return max(1, int(float(override) * 2**20))
        except ValueError:
            pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 4
    except (ValueError, OSError, AttributeError):
        return 2 * 2**30


def working_bytes(shape: tuple[int, ...]) -> int:
    """Memory the tools need for an array of this shape: its float64 working copy."""
    return math.prod(int(n) for n in shape) * 8


def describe_bytes(n: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n / 1e3:.1f} kB"


PIXEL_AXIS_REVERSED = "pixel_axis_reversed"  # meta: frames reversed from the camera's order to the contract's
STAGE_ACCELERATION = "stage_acceleration_mm_s2"  # meta: the most the stage was commanded to accelerate, mm/s²
MAINS_HZ = "mains_hz"  # meta: the mains frequency the rig's lamp runs on, Hz (it flickers at twice it; 0: on DC)
CAMERA_TRIGGER = "camera_trigger"  # meta: what starts each exposure: "hardware" (the stage controller's line, on the
# clock that latches the grating: one clock, none to run apart), "software" or "free-run" (the camera's own clock)
SENSOR_RANGE = "sensor_range_gray"  # meta: [floor, ceiling] the camera's readout clips at, gray (where its bit depth
# does not say: a camera whose float output is clipped)
STAGE_PHASES = "stage_acceleration_phases"  # meta: the stage's commanded phases of acceleration, in the frames'
# clock: [[start s, end s, |acceleration| mm/s²], ...] (between them it was commanded to hold its speed or rest)


class RecordingError(GraytrackError):
    """A recording file or array set that does not follow the contract."""


def acceleration_phases(meta: dict[str, Any]) -> np.ndarray | None:
    """The stage's commanded phases of acceleration a recording's ``meta`` states, as an (n, 3) array of (start s,
    end s, |acceleration| mm/s²) sorted by start; None where it states none. Malformed: RecordingError."""
    phases = meta.get(STAGE_PHASES)
    if phases is None:
        return None
    ok = isinstance(phases, list) and all(
        isinstance(phase, list) and len(phase) == 3 and
        all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in phase)
        for phase in phases)
    table = np.array(phases, dtype=np.float64).reshape(-1, 3) if ok else None
    if table is None or (table[:, 1] < table[:, 0]).any() or (table[:, 2] < 0).any():
        raise RecordingError(f"meta: {STAGE_PHASES} must be a list of [start s, end s ≥ start, acceleration ≥ 0 "
                             f"mm/s²] triples, got {str(phases)[:80]}")
    return table[np.argsort(table[:, 0], kind="stable")]


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

    def flipped(self) -> "Recording":
        """The pixel axis reversed (``--flip``, ``[camera] flip``): for a camera whose u runs against the
        target coordinate, which the contract wants increasing. ``meta["pixel_axis_reversed"]`` says
        the frames are no longer as the camera delivered them (a second flip takes it back)."""
        meta = dict(self.meta)
        if meta.pop(PIXEL_AXIS_REVERSED, False) is not True:
            meta[PIXEL_AXIS_REVERSED] = True
        return Recording(np.ascontiguousarray(self.frames[..., ::-1]), self.t, self.reference, meta)


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
    # (a float recording's extremes answer both of its checks in two passes and no temporary array: a NaN or an
    # infinity is among them wherever one is in the frames, and the largest magnitude is one of them)
    lowest, highest = (float(frames.min()), float(frames.max())) if frames.dtype.kind == "f" else (0.0, 0.0)
    if frames.dtype.kind == "f" and not (math.isfinite(lowest) and math.isfinite(highest)):
        bad = ~np.isfinite(frames).reshape(n_frames, -1).all(axis=1)
        if bad.any():
            raise RecordingError(
                f"frames: {int(bad.sum())} frame(s) hold NaN or infinite gray values (first at frame "
                f"{int(np.argmax(bad))})"
            )
    for key, values in (("t", rec.t), ("reference", rec.reference)):
        if values.shape != (n_frames,):
            raise RecordingError(f"{key}: expected shape ({n_frames},) to match frames, got {values.shape}")
    if frames.dtype.kind == "f" and max(-lowest, highest) > MAX_ABS_GRAY:
        raise RecordingError(f"frames: gray values beyond ±{MAX_ABS_GRAY:g} are not gray levels")
    if not np.isfinite(rec.t).all():
        raise RecordingError("t: holds NaN or infinite times")
    steps = np.diff(rec.t)
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0)) + 1
        raise RecordingError(f"t: times must increase frame by frame; frame {k} is at {rec.t[k]!r} s, "
                             f"frame {k - 1} at {rec.t[k - 1]!r} s")
    if np.isinf(rec.reference).any():
        raise RecordingError("reference: holds infinite values (use NaN for 'no reading')")
    if (np.abs(rec.reference) > MAX_ABS_REFERENCE_MM).any():
        raise RecordingError(f"reference: positions beyond ±{MAX_ABS_REFERENCE_MM:g} mm are not stage positions")
    if not isinstance(rec.meta, dict):
        raise RecordingError("meta: must be a JSON object")
    if STAGE_PHASES in rec.meta:
        acceleration_phases(rec.meta)  # (refused here, with the key named, rather than where it is read)
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
    arrays = {"frames": rec.frames, "t": rec.t, "reference": rec.reference,
              "meta": np.array(json.dumps(rec.meta, sort_keys=True))}
    with open_atomic(path) as fh, zipfile.ZipFile(fh, mode="w", allowZip64=True) as archive:
        for key, array in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED if deflation_pays(array) else zipfile.ZIP_STORED
            with archive.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)
    return path


def deflation_pays(array: np.ndarray) -> bool:
    """Whether deflating ``array`` saves at least ``1 − DEFLATE_WORTH`` of its bytes, judged on samples of it
    spread over the whole (a small array is always deflated: its time is nothing either way)."""
    data = np.ascontiguousarray(array).view(np.uint8).reshape(-1)
    if data.size <= DEFLATE_SAMPLE * DEFLATE_SAMPLES:
        return True
    starts = np.linspace(0, data.size - DEFLATE_SAMPLE, DEFLATE_SAMPLES).astype(np.int64)
    sample = b"".join(data[start:start + DEFLATE_SAMPLE].tobytes() for start in starts)
    return len(zlib.compress(sample, DEFLATE_LEVEL)) <= DEFLATE_WORTH * len(sample)


def load(path: str | os.PathLike[str]) -> Recording:
    """Read and validate a recording; unknown keys are ignored."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    with open(path, "rb") as fh:
        if fh.read(4) != b"PK\x03\x04":
            raise RecordingError(f"{path}: not an .npz recording (no zip archive header)")
    try:
        with zipfile.ZipFile(path) as archive:
            members = {info.filename.removesuffix(".npy"): info for info in archive.infolist()}
            missing = [key for key in ARRAY_KEYS if key not in members]
            if missing:
                raise RecordingError(f"{path}: missing key {missing[0]!r}")
            wanted = [*ARRAY_KEYS, "meta"] if "meta" in members else list(ARRAY_KEYS)
            with contextlib.ExitStack() as opened:
                # each member's header read once: the budget checked on all of them before any data is read, which
                # is then read on from where each header ended (reading every header twice cost a load as much as
                # a small recording's data)
                headers = _check_declared_sizes(archive, {key: members[key] for key in wanted}, opened)
                arrays = {key: _read_member(key, *headers[key]) for key in wanted}
    except RecordingError as exc:
        raise RecordingError(f"{path}: {exc}" if not str(exc).startswith(str(path)) else str(exc)) from None
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError, NotImplementedError) as exc:
        raise RecordingError(f"{path}: not a readable .npz recording ({exc})") from None
    meta_raw = arrays.pop("meta", None)
    meta = _parse_meta(meta_raw, path)
    for key in ("t", "reference"):
        if arrays[key].dtype.kind not in "fiu":
            raise RecordingError(f"{path}: {key}: expected float64, got {arrays[key].dtype}")
    try:
        return Recording(arrays["frames"], arrays["t"], arrays["reference"], meta)
    except RecordingError as exc:
        raise RecordingError(f"{path}: {exc}") from None


# numpy parses a .npy header with ast.literal_eval, and CPython 3.11's AST constructor is not safe
# from two threads at once (it raised "AST constructor recursion depth mismatch" when Dask's threads
# read recordings side by side): headers are parsed one at a time; the data is read in parallel.
_HEADER_LOCK = threading.Lock()
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def _read_header(fh: Any) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, Fortran order, dtype) of the ``.npy`` stream ``fh``, left at the start of its data."""
    version = np.lib.format.read_magic(fh)
    if version not in _HEADER_READERS:
        raise ValueError(f".npy format version {version} is not one numpy writes for arrays like these")
    with _HEADER_LOCK:
        return _HEADER_READERS[version](fh, max_header_size=10_000)


def _npy_header(archive: zipfile.ZipFile, info: zipfile.ZipInfo, key: str,
                opened: contextlib.ExitStack) -> tuple[Any, tuple[int, ...], bool, np.dtype]:
    """The member opened (closed with ``opened``) and left at the start of its data, and shape, Fortran order and
    dtype from its ``.npy`` header, read without reading the array."""
    try:
        fh = opened.enter_context(archive.open(info))
        shape, fortran, dtype = _read_header(fh)
    except Exception as exc:  # noqa: BLE001 - numpy's header parser raises anything from SyntaxError to TokenError
        raise RecordingError(f"{key}: broken .npy header ({type(exc).__name__}: "
                             f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    if not isinstance(shape, tuple) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise RecordingError(f"{key}: broken .npy header (shape {shape!r})")
    if dtype.hasobject:
        raise RecordingError(f"{key}: holds Python objects, which a recording never does")
    return fh, shape, fortran, dtype


def _check_declared_sizes(archive: zipfile.ZipFile, members: dict[str, zipfile.ZipInfo],
                          opened: contextlib.ExitStack) -> dict[str, tuple[Any, tuple[int, ...], bool, np.dtype]]:
    """Refuse before reading when the arrays declared would not fit the memory budget. Returns each member opened
    at the start of its data (closed with ``opened``), with its shape, Fortran order and dtype."""
    budget = memory_budget_bytes()
    total = 0
    headers = {}
    for key, info in members.items():
        fh, shape, fortran, dtype = headers[key] = _npy_header(archive, info, key, opened)
        stored = math.prod(shape) * dtype.itemsize
        if key == "meta" and stored > MAX_META_BYTES:
            raise RecordingError(f"meta: declares {describe_bytes(stored)}, more than a JSON note needs")
        if info.file_size > stored + 4096:  # the header is small; more bytes than the array is a lie
            raise RecordingError(f"{key}: the zip entry inflates to {describe_bytes(info.file_size)}, "
                                 f"more than its declared {shape} {dtype} array")
        total += working_bytes(shape) if key != "meta" else stored
        if total > budget:
            raise RecordingError(
                f"{key}: declares {shape} {dtype}, needing {describe_bytes(total)} in memory, beyond the budget of "
                f"{describe_bytes(budget)} ({BUDGET_ENV} sets it; default a quarter of this machine's memory)")
    return headers


def _read_member(key: str, opened: Any, shape: tuple[int, ...], fortran: bool, dtype: np.dtype) -> np.ndarray:
    """The member's array, read on from the end of its header (checked against the budget by :func:`_npy_header`)."""
    try:
        # a member opened for reading is a ZipExtFile (a BufferedIOBase: readinto), typed IO[bytes]
        fh = cast(zipfile.ZipExtFile, opened)
        if dtype.hasobject:
            raise ValueError("holds Python objects")
        flat = np.empty(math.prod(shape), dtype=dtype)
        buffer = flat.data.cast("B")
        filled = 0
        while filled < len(buffer):  # straight into the array: no second copy of a large recording
            got = fh.readinto(buffer[filled:])
            if not got:
                raise EOFError(f"{filled} of {len(buffer)} bytes")
            filled += got
        return flat.reshape(shape, order="F" if fortran else "C")
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise RecordingError(f"{key}: cannot be read "
                             f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None


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
