"""The sensor's own fixed pattern, rougher than the model's pixel polynomials, measured on calibration's own sweep.

The model's coefficients are smooth in the pixel index (core/models/fourier.py: polynomials of a low degree). What
the sensor adds that is rough from pixel to pixel, or narrower than the polynomials can bend, stays in every frame
as the model's error: each pixel's own gain and dark level (PRNU, DSNU), a glare's bright blob a few pixels wide
fixed to the camera. Tracking held it as white noise on the samples (the calibration's χ² level: 29 on the paper
rig under a 20-gray glare, 54 under 3 % PRNU) and, worse, as something the estimator's states of the light and
the focus chase as the print moves under it, frame after frame: they err with it (the glare's steady run erred 6.1
noise floors where the states held still would err 5.3).

Calibration's sweep sees every pixel at every phase of the print, the position pinned by the grating, so each
sample's pattern is a straight line of what it read against what the model says, ``y = (1 + f)·h + e``, fitted
over the whole sweep (h through the estimator's posterior on each frame). Two things keep that fit honest:

- **Only the rough part**: the fitted ``f`` and ``e`` less their projection on the model's own pixel (and row)
  polynomials. The smooth part is the model's coefficients' (a fit of the sweep put it there) and the
  estimator's light field's; a smooth shape the fit finds anyway is the model's error along the stroke averaged
  over the sweep (scratches on the print leave one), which a run over another stretch of the stroke does not see.
- **The motion decides, as for the maps**: a pattern on the sensor is the same wherever the stage stands, one of
  the print's is not. The sweep is cut into ``STRETCHES`` stretches along the stroke; the pattern fitted on every
  other stretch must predict the rest (and the rest it), sample by sample, beyond what a pattern of noise would
  (``HELD_OUT_Z``), or that sample keeps none.
- **Most frames say so**: a least-squares line is the mean of what a sample read, and a sample that reads two
  values (a telegraph pixel flipping, a glint on a few frames in twenty) has a mean that is neither. With the
  pattern out, a sample keeps it only where it brings most frames' values nearer the model, beyond chance at
  ``MAJORITY_Z`` σ of a fair coin's count (a pattern a quarter of the noise deep passes on calibration's thousand
  frames).

- **It pays where it is for**: the image alone (the grating only checked) must place calibration's own frames
  nearer the grating with the pattern out than without, by ``LEAST_GAIN`` (a 75 % JPEG's blocks leave a pattern
  every test above confirms, which placed the lab's frames 1 % worse).

The estimator's states chase the pattern while it is unknown, so the sweep is tracked again with the first fit
taken out and the whole pattern fitted anew (``PASSES``). With the pattern out the calibration's frames leave less:
the level a frame's χ² is held against, its course along the stroke and its spread from frame to frame
(core/chi2_curve.py) are measured again, on the last check's frames, as the estimator then sees them.

The estimator sees each frame through it (:meth:`FlatField.apply`, before anything else); the model's own
prediction, and today's path, are unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from graytrack.core.chi2_curve import Chi2Curve, frame_spread, measured as measured_chi2_curve

if TYPE_CHECKING:
    from graytrack.core.estimator.filter import Estimator
    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.recording import Recording

FLAT_FIELD = "estimator_flat_field"  # the model's info key it is kept under
FLAT_FIELD_VERSION = 1
STRETCHES = 8  # of the sweep along the stroke: every other one fits the pattern the rest must confirm (even)
PASSES = 2  # fits of the whole pattern: the first with the states chasing it, then with it taken out
MIN_FRAMES = 40  # placed frames of the sweep at least (a few a stretch): else no pattern is measured
HELD_OUT_Z = 3.0  # σ of one sample's test: the χ² (at the calibration's level) a sample's pattern must take out of the
# other stretches' frames beyond what a pattern of noise would (a few levels' worth either way)
MAJORITY_Z = 3.0  # σ of a fair coin's count by which a kept sample's frames must come nearer the model with it out
# of the position error on calibration's own frames (the image alone, against the grating) a pattern must take out: a
# run over another stretch of the stroke errs a few per cent otherwise than calibration's frames with the same model
# (its error along the stroke repeats only where the frames do), so a pattern that pays less than that may cost as much
LEAST_GAIN = 0.05
LEVEL_FLOOR = 0.05  # of the calibration's level at least: a pattern that explains more is taken as that much
# (the noise the fit cannot take out stays; a level near zero would make every later frame fail its test)


@dataclass(frozen=True)
class FlatField:
    """A sample's gray value as the estimator sees it: ``(y − offset) / gain`` of what the camera read, with the
    calibration's χ² ``level`` (per sample, in the model's units), its ``curve`` along the stroke (None: flat) and
    ``spread`` (core/chi2_curve.py) as its frames leave them with the pattern out. ``kept``: the samples a pattern
    is taken out of."""

    gain: np.ndarray
    offset_gray: np.ndarray
    level: float
    curve: Chi2Curve | None
    spread: float
    kept: int

    def apply(self, y: np.ndarray, out: np.ndarray) -> np.ndarray:
        """The frame's samples ``y`` through the pattern, into ``out`` (which may be ``y``)."""
        np.subtract(y, self.offset_gray, out=out)
        np.divide(out, self.gain, out=out)
        return out

    def as_dict(self) -> dict[str, Any]:
        return {"version": FLAT_FIELD_VERSION, "gain": [round(float(v), 6) for v in self.gain],
                "offset_gray": [round(float(v), 4) for v in self.offset_gray], "level": round(self.level, 6),
                "chi2_curve": None if self.curve is None else self.curve.as_dict(), "spread": round(self.spread, 4),
                "kept": self.kept}

    @classmethod
    def from_info(cls, info: dict, samples: int) -> "FlatField | None":
        """The pattern a model's info keeps for ``samples`` samples, None where it keeps none (or one of another
        shape or version: the frames as the model sees them, as before patterns were kept)."""
        body = info.get(FLAT_FIELD)
        if not isinstance(body, dict) or body.get("version") != FLAT_FIELD_VERSION:
            return None
        try:
            gain = np.asarray(body["gain"], dtype=np.float64)
            offset = np.asarray(body["offset_gray"], dtype=np.float64)
            level, spread = float(body["level"]), float(body["spread"])
        except (KeyError, TypeError, ValueError):
            return None
        if gain.shape != (samples,) or offset.shape != (samples,) or not (
                np.all(np.isfinite(gain)) and np.all(gain > 0.0) and np.all(np.isfinite(offset))
                and math.isfinite(level) and level > 0.0 and math.isfinite(spread) and spread >= 1.0):
            return None
        curve = Chi2Curve.from_info({"calibration_chi2_curve": body.get("chi2_curve")})
        return cls(gain, offset, level, curve, spread, int(body.get("kept", 0)))


class _Sums:
    """Each sample's weighed sums of ``h·h, h, 1, h·r, r`` (h the model's value, r what the camera read beyond it,
    both as the camera read them) in each stretch of the stroke."""

    def __init__(self, samples: int, edges: np.ndarray) -> None:
        self.edges = edges
        self.sums = np.zeros((edges.size + 1, 5, samples))

    def add(self, x_mm: float, h: np.ndarray, r: np.ndarray, w: np.ndarray, field: "FlatField | None") -> None:
        into = self.sums[int(np.searchsorted(self.edges, x_mm))]
        if field is not None:  # (back to what the camera read: y = gain·y' + offset)
            gain = field.gain
            r = gain * r + (gain - 1.0) * h + field.offset_gray
            w = w / (gain * gain)
        wh = w * h
        into[0] += wh * h
        into[1] += wh
        into[2] += w
        into[3] += wh * r
        into[4] += w * r


def _line(sums: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's ``(f, e)``: the least-squares line ``r = f·h + e`` of its sums (0 where they hold none)."""
    det = sums[0] * sums[2] - sums[1] * sums[1]
    solvable = det > 1e-12 * np.maximum(sums[0] * sums[2], 1e-300)
    det = np.where(solvable, det, 1.0)
    f = np.where(solvable, (sums[2] * sums[3] - sums[1] * sums[4]) / det, 0.0)
    e = np.where(solvable, (sums[0] * sums[4] - sums[1] * sums[3]) / det, 0.0)
    return f, e


def _rough(f: np.ndarray, e: np.ndarray, basis: np.ndarray, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``f`` and ``e`` less their least-squares projection on ``basis`` (the model's pixel and row polynomials)
    over the samples ``seen``."""
    if not seen.any():
        return f, e
    both = np.stack([f, e], axis=1)
    coeffs = np.linalg.lstsq(basis[seen], both[seen], rcond=None)[0]
    rough = both - basis @ coeffs
    rough[~seen] = 0.0
    return rough[:, 0], rough[:, 1]


def _explained(f: np.ndarray, e: np.ndarray, sums: np.ndarray) -> np.ndarray:
    """Each sample's χ² its ``(f, e)`` takes out of the frames its ``sums`` hold (negative: it adds)."""
    return 2.0 * (f * sums[3] + e * sums[4]) - (f * f * sums[0] + 2.0 * f * e * sums[1] + e * e * sums[2])


def pattern(sums: np.ndarray, basis: np.ndarray, least: float) -> tuple[np.ndarray, np.ndarray]:
    """The rough pattern ``(f, e)`` of the stretches' ``sums`` ``(stretches, 5, samples)``, kept at the samples where
    the one of every other stretch predicts the other stretches' (each half's, fitted alone, takes more than ``least``
    of χ² out of what the other's frames leave beyond their own smooth part, summed over both ways)."""
    seen = sums[:, 2].sum(axis=0) > 0.0
    halves = [sums[0::2].sum(axis=0), sums[1::2].sum(axis=0)]
    rough, rest = [], []
    for half in halves:
        f, e = _line(half)
        f_rough, e_rough = _rough(f, e, basis, seen)
        rough.append((f_rough, e_rough))
        # (what the half's frames leave beyond the smooth part of their own line: the model's and the light's)
        f_smooth, e_smooth = f - f_rough, e - e_rough
        left = half.copy()
        left[3] -= f_smooth * half[0] + e_smooth * half[1]
        left[4] -= f_smooth * half[1] + e_smooth * half[2]
        rest.append(left)
    confirmed = _explained(*rough[0], rest[1]) + _explained(*rough[1], rest[0]) > least
    f, e = _rough(*_line(halves[0] + halves[1]), basis, seen)
    return np.where(confirmed, f, 0.0), np.where(confirmed, e, 0.0)


def _basis(model: "FourierModel") -> np.ndarray:
    """The model's pixel polynomials times its row polynomials, one row a sample (as the estimator's samples run)."""
    pixel = model.pixel_basis()
    rows = model.row_basis() if model.n_rows > 1 else np.ones((1, 1))
    return np.einsum("ri,pj->rpij", rows, pixel).reshape(model.n_rows * model.n_pixels, -1)


class _Votes:
    """Each sample's count of placed frames, and of those whose value the pattern brought nearer the model."""

    def __init__(self, samples: int) -> None:
        self.frames = 0
        self.nearer = np.zeros(samples)

    def add(self, x_mm: float, h: np.ndarray, r: np.ndarray, w: np.ndarray, field: "FlatField | None") -> None:
        # (r: what the sample left with the pattern out, in the frame's units as seen; without it, the pattern's own
        # change of the value there on top)
        if field is None:
            return
        self.frames += 1
        self.nearer += np.abs(r) < np.abs(r + (field.gain - 1.0) / field.gain * h + field.offset_gray / field.gain)

    def majority(self) -> np.ndarray:
        """The samples most frames came nearer at, beyond chance."""
        n = max(self.frames, 1)
        return self.nearer > 0.5 * n + MAJORITY_Z * 0.5 * math.sqrt(n)


def _tracked(estimator: "Estimator", rec: "Recording", reference: np.ndarray, field: FlatField | None,
             sums: "_Sums | _Votes | None") -> tuple[np.ndarray, np.ndarray]:
    """The sweep through ``estimator`` (seeing its frames through ``field``), each placed frame's samples added to
    ``sums``: (the frames' positions, their χ² per sample; NaN where not placed)."""
    n = rec.frames.shape[0]
    x, chi2 = np.full(n, np.nan), np.full(n, np.nan)
    times, readings = np.asarray(rec.t, dtype=np.float64).tolist(), reference.tolist()
    for k in range(n):
        estimate = estimator.update(rec.frames[k], times[k], readings[k])
        if not math.isfinite(estimate.x_mm) or estimate.stale:
            continue
        x[k], chi2[k] = estimate.x_mm, estimate.chi2
        if sums is None:
            continue
        sums.add(estimate.x_mm, *estimator.left(rec.frames[k]), field)
    return x, chi2


def calibration_flat_field(model: "FourierModel", rec: "Recording") -> dict | None:
    """The sensor's rough pattern (:class:`FlatField`, as a document) the estimator measures on calibration's own
    recording ``rec`` with its grating fused; None without a grating, with too few frames placed, where no sample
    holds a pattern the stretches and most frames confirm, or where with it the image places calibration's own
    frames no nearer the grating."""
    from graytrack.core.estimator.filter import Estimator, _calibration_reference, calibration_level
    from graytrack.core.estimator.settings import EstimatorSettings
    from graytrack.core.recording import acceleration_phases

    reference = _calibration_reference(model, rec)
    if reference is None or np.isfinite(reference).sum() < MIN_FRAMES:
        return None
    settings = EstimatorSettings().for_recording(rec.meta)
    phases = acceleration_phases(rec.meta)
    samples = model.n_rows * model.n_pixels
    basis = _basis(model)
    usable = reference[np.isfinite(reference)]
    edges = np.quantile(usable, np.linspace(0.0, 1.0, STRETCHES + 1)[1:-1])
    bare = model.with_changes(info={key: value for key, value in model.info.items() if key != FLAT_FIELD})
    level = calibration_level(bare)

    def run(field: FlatField | None, grating: str, into: "_Sums | _Votes | None" = None):
        estimator = Estimator(bare, settings=settings, grating=grating, stage_phases=phases, flat_field=field)
        return _tracked(estimator, rec, reference, field, into)

    field: FlatField | None = None
    for _ in range(PASSES):
        sums = _Sums(samples, edges)
        _, chi2 = run(field, "fuse", sums)
        if np.isfinite(chi2).sum() < MIN_FRAMES:
            return None
        field = _kept(*pattern(sums.sums, basis, HELD_OUT_Z ** 2 * level), level)
        if field is None:
            return None
    if field is None:  # (no pass made one)
        return None
    # the samples most frames do not come nearer at keep none
    votes = _Votes(samples)
    run(field, "fuse", votes)
    nearer = votes.majority()
    field = _kept(np.where(nearer, field.gain - 1.0, 0.0), np.where(nearer, field.offset_gray, 0.0), level)
    if field is None:
        return None
    # what it is for: the image alone (the grating checked) places calibration's frames nearer the grating with it
    # than without; and the level, its course along the stroke and its spread, as the frames are seen through it
    x, chi2, error = _checked(run(field, "check"), reference)
    _, chi2_before, error_before = _checked(run(None, "check"), reference)
    placed = np.isfinite(chi2) & np.isfinite(chi2_before)
    if placed.sum() < MIN_FRAMES or not np.nanstd(error) < (1.0 - LEAST_GAIN) * np.nanstd(error_before):
        return None
    level *= max(float(np.mean(chi2[placed])) / float(np.mean(chi2_before[placed])), LEVEL_FLOOR)
    good = np.isfinite(chi2)
    curve = measured_chi2_curve(x[good], chi2[good])
    spread = frame_spread(x[good], chi2[good], curve, samples * float(np.mean(model.seen())))
    return FlatField(field.gain, field.offset_gray, level, curve, spread, field.kept).as_dict()


def _kept(f: np.ndarray, e: np.ndarray, level: float) -> FlatField | None:
    """The pattern ``(f, e)`` as a field at the calibration's ``level`` (None where no sample holds one)."""
    kept = int(np.count_nonzero((f != 0.0) | (e != 0.0)))
    return FlatField(1.0 + f, e, level, None, 1.0, kept) if kept else None


def _checked(tracked: tuple[np.ndarray, np.ndarray], reference: np.ndarray) -> tuple[np.ndarray, ...]:
    """(positions, χ² per sample, the positions less the grating's), NaN where a frame was not placed."""
    x, chi2 = tracked
    return x, chi2, x - reference


__all__ = ["FLAT_FIELD", "FlatField", "calibration_flat_field", "pattern"]
