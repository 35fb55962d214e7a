"""Transients: what is compact in space and short in time (glints, reflections, passing dust, hits).

A glint on the print or a particle crossing the view spoils a few neighbouring samples of a few
frames. Those samples say nothing about the position, and nothing about the pixels either: the
pixel that caught a glint in 3 frames of 500 is as good as its neighbours in the other 497. So a
transient is set aside sample by sample (weight 0 for the samples it covers, in the frames it
lasts), never as a whole pixel; a pixel is bad only when it is bad in most frames, which is the
bad-pixel screen's business (core/effects/bad_pixels.py).

What makes a transient, here and in tracking alike (:func:`compact_blobs`): a connected set of
samples of one frame (along the line, and across the rows of a strip) beyond ``GROW_Z`` noise σ,
with at least one beyond ``CORE_Z`` and at least ``MIN_SAMPLES`` of them, narrower than
``MAX_WIDTH_SHARE`` of the line (a change of the whole line is the light's, not a transient), grown
by ``MARGIN_PX`` to take the blob's tails that sink into the noise.

Calibration finds them without any model (:func:`find_transients`): frames sorted by the
reference see nearly the same image as their neighbours along the stroke, so the median of the
neighbours' samples is what the frame should show (a transient lasting a few frames is a
minority among them). Taken pixel by pixel, that median holds what is fixed to the pixels (gains,
defects); taken at the same point of the target (neighbours shifted by their distance along the
stroke over the nominal α·d), what is fixed to the print (dust, scratches, which slide across
the pixels as the stage moves). A transient departs from both. The medians are only taken near
steps between neighbouring frames that jump (a transient begins or ends there): a clean sweep
costs one difference per frame.

Tracking finds them in the frame's residual against the model (core/solvers.py robust_solve,
core/tracking.py): the same blob test, only when the frame's χ² asks for the robust solve.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage

from graytrack.core import kernels

CORE_Z = 8.0  # a transient has a sample this many noise σ off (noise alone: ~1e-15 per sample)
GROW_Z = 3.0  # its support: the connected samples beyond this
MIN_SAMPLES = 3  # a lone sample is a pixel's business (telegraph, noisy), not a blob
MAX_WIDTH_SHARE = 0.25  # wider than this share of the line: not compact
MARGIN_PX = 1  # the support grown by this, along the line and across rows (the tails)
NEIGHBOURS = 8  # frames on each side along the stroke that say what a frame should show
NEIGHBOUR_SPAN_PERIODS = 0.04  # neighbours farther along the stroke than this share of a period: not used
INTERPOLATION_SHARE = 0.25  # of the print's local |Δ²y| allowed for reading a neighbour between two pixels
SUSPECT_Z = 5.5  # a step between neighbouring frames this large (in its noise) may be a transient's edge
PIXEL_MAJORITY = 0.5  # a pixel flagged in more frames than this share is a bad pixel, not a transient
LISTED = 20  # events named one by one in a report
_IN_FRAME = np.zeros((3, 3, 3), dtype=bool)
_IN_FRAME[1] = True  # connectivity within one frame only: rows and pixels, diagonals included
_MARGIN = np.zeros((3, 3, 3), dtype=bool)
_MARGIN[1, 1, :] = _MARGIN[1, :, 1] = True


def compact_blobs(z: np.ndarray, core_z: float = CORE_Z, grow_z: float = GROW_Z,
                  max_width_share: float = MAX_WIDTH_SHARE) -> np.ndarray:
    """Samples of compact transients in normalised residual magnitudes ``z`` ``(K, R, n)``: bool,
    same shape (see the module's docstring for what counts; ``max_width_share`` of the line at most).

    Compiled (:func:`_compiled_blobs`, a flood fill per frame) where numba is there: a tracked frame
    asks this once or twice per robust solve; scipy's labelling costs ~0.3 ms a call."""
    z = np.asarray(z)
    if kernels.COMPILED and z.ndim == 3:
        out = np.zeros(z.shape, dtype=np.bool_)
        _compiled_blobs(np.ascontiguousarray(z, dtype=np.float64), core_z, grow_z,
                        max(max_width_share * z.shape[2], 3), MIN_SAMPLES, MARGIN_PX, out)
        return out
    return _scipy_blobs(z, core_z, grow_z, max_width_share)


def _scipy_blobs(z: np.ndarray, core_z: float, grow_z: float, max_width_share: float) -> np.ndarray:
    """:func:`compact_blobs` by scipy's labelling (the reference the compiled one is held to)."""
    support = z > grow_z
    if not support.any():
        return np.zeros(z.shape, dtype=bool)
    labels, count = ndimage.label(support, structure=_IN_FRAME)
    index = np.arange(1, count + 1)
    sizes = np.bincount(labels.ravel(), minlength=count + 1)[1:]
    peaks = ndimage.maximum(z, labels, index)
    widths = np.array([s[2].stop - s[2].start for s in ndimage.find_objects(labels)])
    keep = (peaks > core_z) & (sizes >= MIN_SAMPLES) & (widths <= max(max_width_share * z.shape[2], 3))
    if not keep.any():
        return np.zeros(z.shape, dtype=bool)
    blobs = np.concatenate(([False], keep))[labels]
    return ndimage.binary_dilation(blobs, structure=_MARGIN, iterations=MARGIN_PX)


def _flood_blobs(z: np.ndarray, core_z: float, grow_z: float, max_width: float, min_samples: int,
                 margin: int, out: np.ndarray) -> None:
    """Per frame of ``z`` (K, R, n): the 8-connected groups of samples beyond ``grow_z``, kept when
    their peak passes ``core_z``, they have ``min_samples`` and span at most ``max_width`` columns;
    kept samples and ``margin`` steps of their 4-neighbours set in ``out``."""
    n_frames, n_rows, n_cols = z.shape
    label = np.zeros((n_rows, n_cols), dtype=np.int64)
    stack = np.empty(n_rows * n_cols, dtype=np.int64)
    members = np.empty(n_rows * n_cols, dtype=np.int64)
    kept = np.zeros((n_rows, n_cols), dtype=np.bool_)
    order = np.empty(n_rows * n_cols, dtype=np.int64)  # the kept samples, then each margin step's new ones
    for k in range(n_frames):
        label[:, :] = 0
        kept[:, :] = False
        current = 0
        n_kept = 0
        for r0 in range(n_rows):
            for c0 in range(n_cols):
                if label[r0, c0] != 0 or not z[k, r0, c0] > grow_z:
                    continue
                current += 1
                label[r0, c0] = current
                top, count = 1, 0
                stack[0] = r0 * n_cols + c0
                peak, low, high = -np.inf, c0, c0
                while top > 0:
                    top -= 1
                    flat = stack[top]
                    members[count] = flat
                    count += 1
                    r, c = flat // n_cols, flat % n_cols
                    peak = max(peak, z[k, r, c])
                    low, high = min(low, c), max(high, c)
                    for dr in range(-1, 2):
                        for dc in range(-1, 2):
                            rr, cc = r + dr, c + dc
                            if 0 <= rr < n_rows and 0 <= cc < n_cols and label[rr, cc] == 0 and z[k, rr, cc] > grow_z:
                                label[rr, cc] = current
                                stack[top] = rr * n_cols + cc
                                top += 1
                if peak > core_z and count >= min_samples and high - low + 1 <= max_width:
                    for i in range(count):
                        kept[members[i] // n_cols, members[i] % n_cols] = True
                        order[n_kept] = members[i]
                        n_kept += 1
        # The margin: each step adds the 4-neighbours of the samples the step before added (those of
        # older ones are in already), so only the blobs' borders are visited, not the frame.
        start = 0
        for _ in range(margin):
            end = n_kept
            for i in range(start, end):
                r, c = order[i] // n_cols, order[i] % n_cols
                for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
                    if 0 <= rr < n_rows and 0 <= cc < n_cols and not kept[rr, cc]:
                        kept[rr, cc] = True
                        order[n_kept] = rr * n_cols + cc
                        n_kept += 1
            start = end
        out[k] = kept


_compiled_blobs = kernels.numba.njit(cache=True, nogil=True)(_flood_blobs) if kernels.COMPILED else _flood_blobs


@dataclass
class Transient:
    """One event: consecutive frames with a blob at the same place on the target."""

    frames: list[int]  # recording frame numbers
    row: int  # row of its brightest sample (0 on one line)
    pixel: int  # pixel of its brightest sample, first frame
    x_mm: float  # target coordinate of that pixel (nominal α·d), where it sits on the print
    peak_gray: float  # largest departure from what the frame should show
    samples: int  # samples set aside over its frames

    def as_dict(self) -> dict[str, Any]:
        return {"frames": [self.frames[0], self.frames[-1]], "row": self.row, "pixel": self.pixel,
                "x_mm": round(self.x_mm, 4), "peak_gray": round(self.peak_gray, 1), "samples": self.samples}


@dataclass
class TransientFindings:
    mask: np.ndarray  # (K, R, n) bool: samples set aside
    events: list[Transient] = field(default_factory=list)

    @property
    def frames(self) -> int:
        return int(self.mask.any(axis=(1, 2)).sum())

    def summary(self) -> dict[str, Any]:
        """What a report says: how many, in how many frames, how many samples, and each one."""
        return {"count": len(self.events), "frames": self.frames, "samples": int(self.mask.sum()),
                "share_of_frames": round(self.frames / max(self.mask.shape[0], 1), 4),
                "events": [event.as_dict() for event in self.events[:LISTED]]}

    def line(self) -> str:
        """One sentence for a command's output."""
        return summary_line(self.summary())


def summary_line(summary: dict[str, Any] | None) -> str:
    """One sentence for a command's output, from :meth:`TransientFindings.summary` (None: none found)."""
    found: dict[str, Any] = summary or {}

    def count(key: str) -> str:  # a report read back may have lost any figure
        value = found.get(key)
        return str(int(value)) if isinstance(value, (int, float)) and math.isfinite(value) else "n/a"

    if not found or count("count") == "0":
        return "transients: none found"
    if count("count") == "n/a":
        return "transients: n/a (the report lost the figure)"
    first = (found.get("events") or [{}])[0]
    where = f", first in frames {first['frames'][0]}-{first['frames'][1]} at pixel {first['pixel']}" if first else ""
    return (f"transients: {count('count')} (glints, reflections, passing dust) in {count('frames')} frame(s), "
            f"{count('samples')} samples set aside{where}; their pixels stay in use")


def _neighbours(x_mm: np.ndarray, period_mm: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each frame's ``NEIGHBOURS`` on each side in the order of the reference ``(K, 2·half)``, which
    of them are near enough along the stroke, and which frames have enough such neighbours."""
    n_frames = x_mm.size
    half = min(NEIGHBOURS, (n_frames - 1) // 2)
    order = np.argsort(x_mm, kind="stable")
    rank = np.empty(n_frames, dtype=np.int64)
    rank[order] = np.arange(n_frames)
    start = np.clip(rank - half, 0, n_frames - 2 * half - 1)
    window = start[:, None] + np.arange(2 * half + 1)  # sorted positions, the frame's own among them
    window = window[window != rank[:, None]].reshape(n_frames, 2 * half)
    neighbours = order[window]
    span = np.inf if not period_mm else NEIGHBOUR_SPAN_PERIODS * float(period_mm)
    near = np.abs(x_mm[neighbours] - x_mm[:, None]) <= span
    return neighbours, near, near.sum(axis=1) >= max(half, 3)


def _median(stack: np.ndarray, missing: np.ndarray | None) -> np.ndarray:
    """Median over axis 1 of the values not ``missing``: half of the missing ones set to +∞ and
    half to −∞ leave the median of the others in place (np.nanmedian costs several times more)."""
    if missing is None or not missing.any():
        return np.median(stack, axis=1)
    signs = np.where(np.cumsum(missing, axis=1) % 2 == 0, np.inf, -np.inf)
    return np.median(np.where(missing, signs, stack), axis=1)


def expected_images(frames: np.ndarray, neighbours: np.ndarray, which: np.ndarray, chunk: int = 64) -> np.ndarray:
    """What frames ``which`` (indices into ``frames`` ``(K, R, n)``) should show pixel by pixel,
    model-free: the median of their neighbours along the stroke (``neighbours`` from
    :func:`_neighbours`, −1 where not near): what is fixed to the pixels (their gains, defects)
    and what changes slowly with the position is in it, a transient is not."""
    by_pixel = np.empty((which.size,) + frames.shape[1:])
    for j0 in range(0, which.size, chunk):
        index = neighbours[which[j0:j0 + chunk]]
        stack = frames[np.maximum(index, 0)].astype(np.float64)  # (B, N, R, n)
        by_pixel[j0:j0 + chunk] = _median(stack, np.broadcast_to((index < 0)[:, :, None, None], stack.shape))
    return by_pixel


def _suspects(frames: np.ndarray, x_mm: np.ndarray, sigma_gray: float, near_span_mm: float) -> np.ndarray:
    """Frames worth the neighbour medians (bool ``(K,)``): within ``NEIGHBOURS`` along the stroke of
    a step between neighbouring frames that jumps somewhere by more than ``SUSPECT_Z`` noise σ (a
    transient begins or ends there; a clean sweep has none, and costs a difference per frame)."""
    order = np.argsort(x_mm, kind="stable")
    step = np.diff(frames[order], axis=0)
    step -= np.median(step, axis=2, keepdims=True)  # a row's offset (banding, light)
    spread = 1.4826 * np.median(np.abs(step), axis=(1, 2))
    scale = np.maximum(spread, np.sqrt(2.0) * float(sigma_gray))
    jumps = (np.abs(step).max(axis=(1, 2)) > SUSPECT_Z * scale) & (np.abs(np.diff(x_mm[order])) <= near_span_mm)
    marked = np.zeros(x_mm.size, dtype=bool)
    marked[:-1] |= jumps
    marked[1:] |= jumps
    marked = ndimage.binary_dilation(marked, iterations=NEIGHBOURS) if marked.any() else marked
    suspects = np.empty_like(marked)
    suspects[order] = marked
    return suspects


def target_aligned(frames: np.ndarray, x_mm: np.ndarray, neighbours: np.ndarray, pitch_mm: float,
                   which: np.ndarray) -> np.ndarray:
    """The neighbours' median at the same point of the *target* for frames ``which``: what is fixed
    to the print (dust, a scratch, a sharp edge) slides across the pixels as the stage moves and is
    in this median, a transient is not. ``neighbours`` as from :func:`expected_images` (−1: not near)."""
    index = neighbours[which]
    stack = frames[np.maximum(index, 0)].astype(np.float64)
    shift = (x_mm[which, None] - x_mm[np.maximum(index, 0)]) / float(pitch_mm)
    n = stack.shape[-1]
    where = np.arange(n) + shift[:, :, None, None]  # pixel of the neighbour that sees the same point
    low = np.floor(where)
    frac = where - low
    missing = (low < 0) | (low > n - 2) | (index < 0)[:, :, None, None]
    low = np.clip(low, 0, n - 2).astype(np.intp)
    shape = stack.shape
    left = np.take_along_axis(stack, np.broadcast_to(low, shape), axis=-1)
    right = np.take_along_axis(stack, np.broadcast_to(low + 1, shape), axis=-1)
    with np.errstate(invalid="ignore"):  # a sample no neighbour sees: ±∞ in the middle, NaN
        aligned = _median(left + frac * (right - left), np.broadcast_to(missing, shape))
    return np.where(np.isfinite(aligned), aligned, np.nan)


def _without_common_mode(residual: np.ndarray, level: np.ndarray) -> np.ndarray:
    """The residual less an offset per row and a gain per frame: a light that changed between
    neighbours along the stroke (flicker, a step) is common to the line, not a transient."""
    residual = residual - np.median(residual, axis=2, keepdims=True)
    level = level - level.mean(axis=(1, 2), keepdims=True)
    scale = 1.4826 * np.median(np.abs(residual), axis=(1, 2), keepdims=True) + 1e-12
    inlier = np.abs(residual) < 4.0 * scale
    slope = (residual * level * inlier).sum(axis=(1, 2), keepdims=True) / (
        (level * level * inlier).sum(axis=(1, 2), keepdims=True) + 1e-12)
    return residual - slope * level


def _normalised(residual: np.ndarray, floor: float, allowance: np.ndarray | float = 0.0) -> np.ndarray:
    """|residual| in units of the frame's robust spread (never below the noise floor), plus an
    allowance where the expectation itself is uncertain."""
    spread = 1.4826 * np.median(np.abs(residual), axis=(1, 2), keepdims=True)
    return np.abs(residual) / (np.maximum(spread, floor) + allowance)


def find_transients(frames: np.ndarray, x_mm: np.ndarray, sigma_gray: float, period_mm: float | None = None,
                    pitch_mm: float | None = None, frame_numbers: np.ndarray | None = None) -> TransientFindings:
    """Transients in calibration frames ``(K, R, n)`` taken at reference positions ``x_mm``,
    without a model (module docstring). ``frame_numbers`` name the frames in reports (default
    0..K−1); ``pitch_mm`` (nominal α·d) places each event on the target."""
    frames = np.asarray(frames, dtype=np.float64)
    n_frames = frames.shape[0]
    numbers = np.arange(n_frames) if frame_numbers is None else np.asarray(frame_numbers)
    if n_frames < 7:
        return TransientFindings(np.zeros(frames.shape, dtype=bool))
    x_mm = np.asarray(x_mm, dtype=np.float64)
    neighbours, near, enough = _neighbours(x_mm, period_mm)
    span = np.inf if not period_mm else NEIGHBOUR_SPAN_PERIODS * float(period_mm)
    which = np.flatnonzero(_suspects(frames, x_mm, sigma_gray, span) & enough)
    if not which.size:
        return TransientFindings(np.zeros(frames.shape, dtype=bool))
    neighbours = np.where(near, neighbours, -1)
    expected = expected_images(frames, neighbours, which)
    floor = float(sigma_gray) * 1.05  # the median of 2·NEIGHBOURS noisy samples adds ~(1.25²/16) of σ²
    residual = _without_common_mode(frames[which] - expected, expected)
    z = _normalised(residual, floor)
    cores = (z > CORE_Z).any(axis=(1, 2))
    if pitch_mm and cores.any():
        # Only what departs from both is a transient. Where the print has sharp structure the
        # target-aligned median carries an interpolation error of up to |Δ²y|/8: allowed for.
        listed = np.flatnonzero(cores)
        for part in np.array_split(listed, max(1, listed.size // 64)):
            by_target = target_aligned(frames, x_mm, neighbours, pitch_mm, which[part])
            by_target = np.where(np.isfinite(by_target), by_target, expected[part])
            aligned = _without_common_mode(frames[which[part]] - by_target, by_target)
            curvature = np.abs(np.diff(by_target, n=2, axis=2))
            curvature = np.pad(ndimage.maximum_filter1d(curvature, 3, axis=2), ((0, 0), (0, 0), (1, 1)), mode="edge")
            z[part] = np.minimum(z[part], _normalised(aligned, floor, INTERPOLATION_SHARE * curvature))
    z[~cores] = np.minimum(z[~cores], CORE_Z)  # no core: no transient
    mask = np.zeros(frames.shape, dtype=bool)
    mask[which] = compact_blobs(z)
    full = np.zeros(frames.shape)
    full[which] = residual
    residual = full
    often = mask.mean(axis=0) > PIXEL_MAJORITY  # bad in most frames: a pixel's defect, not a transient
    mask &= ~often
    return TransientFindings(mask, _events(mask, residual, x_mm, numbers, pitch_mm))


def _events(mask: np.ndarray, residual: np.ndarray, x_mm: np.ndarray, numbers: np.ndarray,
            pitch_mm: float | None) -> list[Transient]:
    """Blobs of consecutive frames at the same place on the target joined into events."""
    pitch = float(pitch_mm) if pitch_mm else 1.0
    events: list[Transient] = []
    open_events: list[tuple[int, Transient]] = []  # (last frame index, event)
    for k in np.flatnonzero(mask.any(axis=(1, 2))):
        labels, count = ndimage.label(mask[k], structure=np.ones((3, 3), dtype=bool))
        still_open = []
        for blob in range(1, count + 1):
            inside = labels == blob
            size = np.where(inside, np.abs(residual[k]), -1.0)
            r, u = np.unravel_index(int(np.argmax(size)), size.shape)
            x_target = float(x_mm[k]) + pitch * u
            match = next((event for last, event in open_events
                          if last == k - 1 and abs(event.x_mm - x_target) <= 4 * pitch), None)
            if match is None:
                match = Transient([int(numbers[k])], int(r), int(u), x_target, float(size.max()), 0)
                events.append(match)
            elif int(numbers[k]) not in match.frames:
                match.frames.append(int(numbers[k]))
            match.peak_gray = max(match.peak_gray, float(size.max()))
            match.samples += int(inside.sum())
            still_open.append((int(k), match))
        open_events = still_open
    return events
