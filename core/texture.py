"""Print texture learned while tracking: marks fixed to the print (dust settling, a scratch, a fibre)
that arrived after calibration, learned into the model from the frames themselves.

A speck that lands on the print during a run is, to the calibrated model, a residual the robust
solve sets aside (core/transients.py); as it piles up, frames lose so many samples that they are
not placed, and those placed lose the information of the samples set aside. But a mark fixed to
the print is not a transient: it comes back at the same *target coordinate* (the frame's position
plus the pixel's place on the target) on every frame that sees it, at whatever pixel sees it. That
is evidence a transient (a glint, a particle passing) or a pixel gone bad never leaves.

A candidate is opened where a frame sets samples aside. From then on, every placed frame that sees
its stretch of the target adds its residual there to a least-squares fit of a relative reflectance
m(x_w) on the target map's grid (core/effects/target_map.py: piecewise-linear in the target
coordinate, a row for each model row, nodes a quarter of a pixel footprint apart: what a target
map fitted at calibration would have held). The candidate is learned when, over enough frames and
enough travel of the print across the pixels, that fit is
- consistent: its χ² per degree of freedom is what noise (and the grid's own misfit) leaves, so the
  frames agree on one shape at one target coordinate (a glint gone after 3 frames does not);
- fixed to the print rather than to the camera: it fits better, by 5σ, than a change of each
  pixel's response would (a pixel gone bad follows the camera, not the print);
- significant: its deepest node is beyond ``SIGNIFICANT_Z`` of its own uncertainty.

A learned mark's samples count again: each frame that sees it is divided by 1 + m at its
predicted position (and again at the position that gives), and those samples' variance grows by
the mark's own, (y·σ_m)², from its fit's covariance scaled by the spread of its observations. The
mark goes on being refined by every frame that sees it; one that stops fitting (blown off the
print) is dropped again. Steady runs open a candidate only where a frame sets samples aside and
learn nothing (the false-learning rate is measured in docs/robustness.md).
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from graytrack.core.effects.target_map import MAX_MAP_STEPS
from graytrack.core.frame_kernel import CUT_SIGMA
from graytrack.core.models.fourier import FourierModel, map_lookup
from graytrack.core.solvers import FrameSolution, GeneralBatch, TrigPolyBatch, robust_solve

STEPS_PER_PIXEL = MAX_MAP_STEPS  # a quarter of a pixel footprint: specks narrower than a pixel keep their shape
MARGIN_PX = 1.5  # a candidate's stretch beyond the samples set aside (a speck's faint tails)
MAX_SPAN_PX = 16.0  # wider than this: not a mark (a shadow, the light), left to the light's solve
MIN_FRAMES = 10  # frames that saw a candidate before it may be learned
MIN_TRAVEL_PX = 1.5  # pixels the print moved under it: every node seen by two pixels, a pixel's defect shown up
SIGNIFICANT_Z = 6.0  # its deepest node this many of its own σ from 0
MOVES_CHI2 = 25.0  # χ² by which fixed-to-the-print beats fixed-to-the-pixels (5σ)
CONSISTENT_SPREADS = 5.0  # χ² within this many of its spreads of its degrees of freedom ...
# ... plus this share of the mark's own signal (Σ w r²): the grid's misfit of a speck's shape (a
# quarter-pixel hat basis leaves a few % of a sharp speck's edges). A glint that came and went, a
# pixel gone bad seen by the print's other pixels, leave most of their signal unexplained.
MISFIT_SHARE = 0.1
PRIOR_SIGMA = 0.5  # a mark changes the light by less than about half: what holds a node few frames saw
GIVE_UP_TRAVEL_PX = 8.0  # a candidate not learned after the print moved this far under it: dropped
GIVE_UP_FRAMES = 400  # ... or after this many frames that saw it (a stage standing still)
MAX_CANDIDATES = 64  # open candidates at most (the oldest dropped first)
REFIT_EVERY = 5  # frames that saw a mark between two fits of it
REFUSED_FRAMES = 100  # pixels whose candidate followed the camera open none for this long
CHANGED_FRAMES = 3  # frames in a row with samples beyond a learned mark's cut: it changed (more dust landed on it)


@dataclass
class Mark:
    """One stretch of the target (nodes ``first``..``first + size − 1`` of the grid, every model
    row) and the normal equations of its relative reflectance, frame by frame."""

    first: int
    size: int
    rows: int
    opened: int  # frame number that opened it
    diag: np.ndarray = field(init=False)
    off: np.ndarray = field(init=False)
    rhs: np.ndarray = field(init=False)
    sum_rr: float = 0.0  # Σ w r² over its observations
    samples: int = 0
    frames: int = 0
    pixel_aa: dict[int, float] = field(default_factory=dict)  # the camera-fixed alternative: Σ w a² per sample
    pixel_ar: dict[int, float] = field(default_factory=dict)  # ... and Σ w a r
    low_px: float = math.inf  # pixel columns its centre was seen at
    high_px: float = -math.inf
    last_seen: int = 0
    since_fit: int = 0
    learned_at: int = -1  # frame at which it was learned (−1: a candidate)
    relearning: bool = False  # it changed (more dust landed on it): fresh evidence gathers while the old m applies
    values: np.ndarray | None = None  # m per node (R, size), after a fit
    sigma: np.ndarray | None = None  # its standard error (∞ where no frame saw the node)
    applied: np.ndarray | None = None  # the m frames are corrected by (the last fit that was ready; None: a candidate)
    applied_sigma: np.ndarray | None = None
    chi2_dof: float = math.nan
    moves_chi2: float = 0.0  # χ² the camera-fixed alternative leaves beyond this fit
    peak_z: float = 0.0
    outlying: int = 0  # frames in a row in which samples departed from the learned mark

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the evidence (a mark that changed starts again as a candidate on its stretch)."""
        self.diag = np.zeros((self.rows, self.size))
        self.off = np.zeros((self.rows, self.size - 1))
        self.rhs = np.zeros((self.rows, self.size))
        self.sum_rr, self.samples, self.frames, self.since_fit, self.outlying = 0.0, 0, 0, 0, 0
        self.pixel_aa, self.pixel_ar = {}, {}
        self.low_px, self.high_px = math.inf, -math.inf
        self.values, self.sigma = None, None
        self.chi2_dof, self.moves_chi2, self.peak_z = math.nan, 0.0, 0.0

    @property
    def learned(self) -> bool:
        return self.applied is not None

    @property
    def travel_px(self) -> float:
        return self.high_px - self.low_px if self.frames else 0.0

    def extend(self, first: int, last: int) -> None:
        """Grow the stretch to nodes ``first..last`` (the new nodes unseen so far)."""
        low, high = min(first, self.first), max(last, self.first + self.size - 1)
        if low == self.first and high == self.first + self.size - 1:
            return
        before, after = self.first - low, high - (self.first + self.size - 1)
        pad = ((0, 0), (before, after))
        self.diag, self.off, self.rhs = np.pad(self.diag, pad), np.pad(self.off, pad), np.pad(self.rhs, pad)
        if self.values is not None:
            self.values = np.pad(self.values, pad)
            self.sigma = np.pad(self.sigma, pad, constant_values=np.inf)
        if self.applied is not None:
            self.applied = np.pad(self.applied, pad)
            self.applied_sigma = np.pad(self.applied_sigma, pad, constant_values=PRIOR_SIGMA)
        self.first, self.size = low, high - low + 1

    def fit(self) -> None:
        """m from the normal equations, row by row; its σ from their inverse, scaled by the spread of
        the observations about the fit; the χ² the camera-fixed alternative leaves beyond it."""
        values, sigma = np.zeros_like(self.rhs), np.full_like(self.rhs, np.inf)
        explained, seen_nodes = 0.0, 0
        variances = []
        for r in range(self.rows):
            seen = self.diag[r] > 0.0
            if not seen.any():
                continue
            normal = np.diag(self.diag[r]) + np.diag(self.off[r], 1) + np.diag(self.off[r], -1)
            normal[np.diag_indices(self.size)] += 1.0 / PRIOR_SIGMA**2
            inverse = np.linalg.inv(normal)
            values[r] = inverse @ self.rhs[r]
            explained += float(values[r] @ self.rhs[r])
            variances.append((r, seen, np.diag(inverse)))
            seen_nodes += int(seen.sum())
        dof = max(self.samples - seen_nodes, 1)
        chi2 = max(self.sum_rr - explained, 0.0)
        self.chi2_dof = chi2 / dof
        inflate = max(1.0, self.chi2_dof)
        for r, seen, variance in variances:
            sigma[r, seen] = np.sqrt(np.maximum(variance[seen], 0.0) * inflate)
        self.values, self.sigma = values, sigma
        pixel_explained = sum(ar * ar / aa for p, (aa, ar) in
                              ((p, (aa, self.pixel_ar[p])) for p, aa in self.pixel_aa.items()) if aa > 0.0)
        pixel_chi2 = max(self.sum_rr - pixel_explained, 0.0)
        self.moves_chi2 = pixel_chi2 - chi2 - (seen_nodes - len(self.pixel_aa))  # each side's unknowns allowed for
        finite = np.isfinite(sigma) & (sigma > 0.0) & (sigma < 0.5 * PRIOR_SIGMA)  # nodes the frames tell
        self.peak_z = float((np.abs(values[finite]) / sigma[finite]).max()) if finite.any() else 0.0
        self.since_fit = 0

    def consistent(self) -> bool:
        """The frames agree on one shape at one target coordinate (what is left is noise and misfit)."""
        dof = max(self.samples - int((self.diag > 0).sum()), 1)
        return self.chi2_dof * dof <= dof + CONSISTENT_SPREADS * math.sqrt(2.0 * dof) + MISFIT_SHARE * self.sum_rr

    def ready(self) -> bool:
        """Seen enough, moving with the print, consistent and significant: learn it."""
        return (self.frames >= MIN_FRAMES and self.travel_px >= MIN_TRAVEL_PX and self.consistent()
                and self.moves_chi2 > MOVES_CHI2 and self.peak_z > SIGNIFICANT_Z)


@dataclass
class TextureEvent:
    frame: int
    what: str  # "learned" or "dropped"
    mark: dict[str, Any]


class Texture:
    """The marks learned on the print in one run (and the candidates on their way), for one model.

    ``corrected`` gives the frame to solve (its learned marks divided out, their samples weighted
    by the marks' uncertainty); ``observe`` takes the solved frame's evidence. Both cost nothing
    while there is no mark and no sample is set aside."""

    def __init__(self, model: FourierModel):
        self.model = model
        self.step_mm = model.pixel_pitch_mm / STEPS_PER_PIXEL
        # on the grid of the model's own target map when it has one (a learned mark adds into it)
        self.origin_mm = float(model.target_map_origin_mm) if model.target_map is not None else 0.0
        if model.target_map is not None:
            ratio = model.target_map_step_mm / self.step_mm
            if abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1:
                self.step_mm = model.target_map_step_mm / round(ratio)
        offsets = model.target_offset()  # (R, n)
        self.offsets = offsets.reshape(-1)
        self.rows = model.n_rows
        self.n_pixels = model.n_pixels
        self.row_of = np.repeat(np.arange(self.rows), self.n_pixels)
        self.column_of = np.tile(np.arange(self.n_pixels), self.rows)
        self.view_mm = (float(offsets.min()), float(offsets.max()))
        self.marks: list[Mark] = []
        self.events: list[TextureEvent] = []
        self.refused_until = np.zeros(self.n_pixels, dtype=np.int64)
        self.refused = 0
        self.corrected_px = 0  # samples the last frame had corrected by a learned mark

    # ------------------------------------------------------------------ the frame to solve
    def corrected(self, tracker, batch: GeneralBatch | TrigPolyBatch, k: int, x_guess: float,
                  free: bool, gain: float, offset: float) -> tuple[GeneralBatch | TrigPolyBatch, int]:
        """Batch frame ``k`` with the learned marks in view divided out, as a one-frame batch (or the
        batch itself when no learned mark is in view). The marks are read at the predicted position,
        then at the position a first solve of the corrected frame gives."""
        self.corrected_px = 0
        if not math.isfinite(x_guess) or not any(mark.learned for mark in self.marks):
            return batch, k
        y, w = batch.frames[k], batch.weights(k)
        first = self._divided(y, w, x_guess)
        if first is None:
            return batch, k
        single = self._batch(tracker, first[0], first[1])
        start = FrameSolution(x_guess, float("nan"), 0.0, 0, gain, offset)
        trial = robust_solve(single, 0, start, free, tracker.settings, None, tracker.chi2_limit, tracker.layout)
        x_at = trial.x_mm if math.isfinite(trial.x_mm) and abs(trial.x_mm - x_guess) < self.model.pixel_pitch_mm \
            else x_guess
        again = self._divided(y, w, x_at)
        if again is None:
            return batch, k
        self.corrected_px = int(again[2])
        return self._batch(tracker, again[0], again[1]), 0

    def _divided(self, y: np.ndarray, w: np.ndarray, x_mm: float):
        """(y / (1 + m), its weights, samples corrected) at position ``x_mm``; None: no learned mark in view."""
        factor, variance = np.ones_like(y), np.zeros_like(y)
        touched = 0
        for mark in self.marks:
            if not mark.learned:
                continue
            where = self._inside(mark, x_mm)
            if where is None:
                continue
            samples, cell, frac = where
            rows = self.row_of[samples]
            m = mark.applied[rows, cell] * (1.0 - frac) + mark.applied[rows, cell + 1] * frac
            s2 = np.square(mark.applied_sigma[rows, cell]) * (1.0 - frac) + \
                np.square(mark.applied_sigma[rows, cell + 1]) * frac
            factor[samples] *= 1.0 + m
            variance[samples] += s2
            touched += samples.size
        if not touched:
            return None
        factor = np.maximum(factor, 0.05)  # a mark never darkens a sample to nothing
        corrected = y / factor
        with np.errstate(divide="ignore", invalid="ignore"):
            noise = np.where(w > 0.0, 1.0 / np.where(w > 0.0, w, 1.0) / (factor * factor), np.inf)
            weights = np.where(w > 0.0, 1.0 / (noise + corrected * corrected * variance), 0.0)
        return corrected, np.nan_to_num(weights, nan=0.0, posinf=0.0), touched

    @staticmethod
    def _batch(tracker, frame: np.ndarray, weights: np.ndarray):
        if tracker.fast_path:
            return TrigPolyBatch(tracker.tables, frame[None], weights[None], evaluator=tracker.evaluator)
        return GeneralBatch.one(tracker.evaluator, frame[None].copy(), weights[None])

    def _inside(self, mark: Mark, x_mm: float):
        """Samples whose target coordinate at ``x_mm`` lies on the mark's stretch: (samples, cell, frac)."""
        lo = self.origin_mm + self.step_mm * mark.first
        hi = lo + self.step_mm * (mark.size - 1)
        if x_mm + self.view_mm[1] < lo or x_mm + self.view_mm[0] >= hi:
            return None
        position = (x_mm + self.offsets - lo) / self.step_mm
        samples = np.flatnonzero((position >= 0.0) & (position < mark.size - 1))
        if not samples.size:
            return None
        cell = np.floor(position[samples]).astype(np.int64)
        return samples, cell, position[samples] - cell

    # ------------------------------------------------------------------ evidence
    def observe(self, tracker, batch: GeneralBatch | TrigPolyBatch, k: int, solution: FrameSolution,
                placed: bool, frame: int) -> None:
        """Add frame ``k``'s residual (the frame as recorded, at its solution) to every mark it sees;
        open candidates where it set samples aside; learn, refine or drop marks. A frame not placed
        only for the share of its samples set aside (the marks not learned yet) still tells them:
        the samples kept fit, and without it a print dusty enough to lose frames is never learned."""
        fits = solution.rms_gray <= tracker.residual_limit_gray and solution.iterations > 0
        if not math.isfinite(solution.x_mm) or not (placed or fits):
            return
        x = solution.x_mm
        set_aside = solution.rejected > 0 or solution.transient_px > 0
        in_view = [mark for mark in self.marks if self._inside(mark, x) is not None]
        if not set_aside and not in_view:
            return
        values = tracker.evaluator.evaluate(np.array([x]))[0][0]
        scale = solution.gain * values + solution.offset  # what the frame would show without the marks
        y, w = batch.frames[k], batch.weights(k)
        residual = y - scale
        for mark in in_view:
            self._add(mark, x, residual, scale, w, frame)
        if set_aside:
            self._open(x, residual, w, solution, frame)
        self._review(frame)

    def _add(self, mark: Mark, x: float, residual: np.ndarray, scale: np.ndarray, w: np.ndarray, frame: int) -> None:
        samples, cell, frac = self._inside(mark, x)
        weights = w[samples]
        r, a = residual[samples], scale[samples]
        keep = weights > 0.0
        if mark.learned and not mark.relearning:  # a transient on top of the mark (a glint) is no evidence of it
            rows = self.row_of[samples]
            applied, spread = mark.applied, mark.applied_sigma
            predicted = a * (applied[rows, cell] * (1.0 - frac) + applied[rows, cell + 1] * frac)
            allowance = np.abs(a) * np.maximum(spread[rows, cell], spread[rows, cell + 1])
            inside = np.abs(r - predicted) <= CUT_SIGMA * np.sqrt(1.0 / np.maximum(weights, 1e-300) + allowance**2)
            departed = bool((keep & ~inside).any())
            mark.outlying = mark.outlying + 1 if departed else 0
            if mark.outlying >= CHANGED_FRAMES:  # the same stretch departs frame after frame: the mark changed
                self.events.append(TextureEvent(frame, "changed", self.describe(mark)))
                applied, applied_sigma, learned_at = mark.applied, mark.applied_sigma, mark.learned_at
                mark.reset()  # fresh evidence from here on; the old m goes on correcting until it is ready
                mark.applied, mark.applied_sigma, mark.learned_at, mark.relearning = \
                    applied, applied_sigma, learned_at, True
            else:
                keep &= inside
        samples, cell, frac, weights, r, a = (v[keep] for v in (samples, cell, frac, weights, r, a))
        if not samples.size:
            return
        rows = self.row_of[samples]
        left, right = a * (1.0 - frac), a * frac
        flat = rows * mark.size + cell
        total = mark.rows * mark.size
        mark.diag += (np.bincount(flat, weights * left * left, total)
                      + np.bincount(flat + 1, weights * right * right, total)).reshape(mark.rows, mark.size)
        off_flat = rows * (mark.size - 1) + cell
        mark.off += np.bincount(off_flat, weights * left * right, mark.rows * (mark.size - 1)).reshape(
            mark.rows, mark.size - 1)
        mark.rhs += (np.bincount(flat, weights * left * r, total)
                     + np.bincount(flat + 1, weights * right * r, total)).reshape(mark.rows, mark.size)
        mark.sum_rr += float(weights @ (r * r))
        mark.samples += samples.size
        for p, aa, ar in zip(samples.tolist(), (weights * a * a).tolist(), (weights * a * r).tolist()):
            mark.pixel_aa[p] = mark.pixel_aa.get(p, 0.0) + aa
            mark.pixel_ar[p] = mark.pixel_ar.get(p, 0.0) + ar
        centre = (self.origin_mm + self.step_mm * (mark.first + 0.5 * (mark.size - 1)) - x) / self.model.pixel_pitch_mm
        mark.low_px, mark.high_px = min(mark.low_px, centre), max(mark.high_px, centre)
        mark.frames += 1
        mark.since_fit += 1
        mark.last_seen = frame

    def _open(self, x: float, residual: np.ndarray, w: np.ndarray, solution: FrameSolution, frame: int) -> None:
        """Candidates where the frame set samples aside (runs of neighbouring columns), unless a mark
        already covers them or their pixels just showed a defect that follows the camera."""
        if solution.rejected_mask is not None and solution.rejected_mask.shape == residual.shape:
            outlying = np.asarray(solution.rejected_mask, dtype=bool)
        else:
            outlying = np.abs(residual) * np.sqrt(w) > CUT_SIGMA
        columns = np.zeros(self.n_pixels, dtype=bool)
        columns[self.column_of[outlying]] = True
        columns &= self.refused_until <= frame
        if not columns.any():
            return
        edges = np.flatnonzero(np.diff(np.concatenate(([0], columns.astype(np.int8), [0]))))
        pitch = self.model.pixel_pitch_mm
        centre_row = self.offsets.reshape(self.rows, self.n_pixels)[self.rows // 2]
        for start, stop in zip(edges[::2], edges[1::2]):
            if (stop - start) > MAX_SPAN_PX:
                continue
            lo = x + centre_row[start] - MARGIN_PX * pitch - self._row_reach()
            hi = x + centre_row[stop - 1] + MARGIN_PX * pitch + self._row_reach()
            first = int(math.floor((lo - self.origin_mm) / self.step_mm))
            last = int(math.ceil((hi - self.origin_mm) / self.step_mm))
            for mark in self.learned:  # a learned mark keeps its stretch (what lands on it, it relearns)
                end = mark.first + mark.size - 1
                if mark.first <= first and last <= end:
                    first = last + 1
                elif mark.first <= last <= end:
                    last = mark.first
                elif mark.first <= first <= end:
                    first = end
            if last - first < 2:
                continue
            overlapping = [m for m in self.marks if not m.learned and m.first <= last and first <= m.first + m.size - 1]
            if overlapping:
                keep = overlapping[0]
                for other in overlapping[1:]:  # grown together: the older one holds the stretch
                    keep.extend(other.first, other.first + other.size - 1)
                    self.marks.remove(other)
                keep.extend(first, last)
                if keep.size * self.step_mm > MAX_SPAN_PX * pitch:
                    self.marks.remove(keep)
                continue
            if len(self.marks) >= MAX_CANDIDATES:
                oldest = next((m for m in self.marks if not m.learned), None)
                if oldest is None:
                    return
                self.marks.remove(oldest)
            self.marks.append(Mark(first, last - first + 1, self.rows, frame, last_seen=frame))

    def _row_reach(self) -> float:
        """How far the rows' views of one point differ along the target (a tilted strip)."""
        offsets = self.offsets.reshape(self.rows, self.n_pixels)[:, 0]
        return float(offsets.max() - offsets.min()) / 2.0

    def _review(self, frame: int) -> None:
        """Refit the marks that saw enough new frames; learn the candidates that are ready, drop the
        hopeless ones and the learned ones that stopped fitting."""
        for mark in list(self.marks):
            due = mark.since_fit >= REFIT_EVERY or (not mark.learned and mark.frames >= MIN_FRAMES and mark.since_fit)
            if due and mark.frames:
                mark.fit()
                if mark.learned and not mark.relearning:
                    if mark.consistent():
                        mark.applied, mark.applied_sigma = mark.values, mark.sigma  # refined by the new frames
                    else:
                        self.marks.remove(mark)
                        self.events.append(TextureEvent(frame, "dropped", self.describe(mark)))
                elif mark.ready():
                    mark.applied, mark.applied_sigma, mark.relearning = mark.values, mark.sigma, False
                    mark.learned_at = frame
                    self.events.append(TextureEvent(frame, "learned", self.describe(mark)))
            if mark.learned:
                if mark.relearning and (mark.travel_px > GIVE_UP_TRAVEL_PX or mark.frames > GIVE_UP_FRAMES):
                    self.marks.remove(mark)  # what landed on it cannot be told apart: it is no mark any more
                    self.events.append(TextureEvent(frame, "dropped", self.describe(mark)))
                continue
            if mark.travel_px > GIVE_UP_TRAVEL_PX or mark.frames > GIVE_UP_FRAMES:
                self.marks.remove(mark)
                if mark.values is not None and mark.moves_chi2 < 0.0:  # it followed the camera: a pixel's defect
                    self._refuse(mark, frame)
            elif frame - mark.last_seen > GIVE_UP_FRAMES:
                self.marks.remove(mark)

    def _refuse(self, mark: Mark, frame: int) -> None:
        """The pixels that carried a candidate's residual open no candidate for a while."""
        worst = max(mark.pixel_aa, key=lambda p: abs(mark.pixel_ar[p]) / math.sqrt(mark.pixel_aa[p])
                    if mark.pixel_aa[p] > 0 else 0.0)
        column = int(self.column_of[worst])
        self.refused_until[max(column - 1, 0):column + 2] = frame + REFUSED_FRAMES
        self.refused += 1

    # ------------------------------------------------------------------ what was learned
    def describe(self, mark: Mark) -> dict[str, Any]:
        """Where a mark is, how deep, how sure: its deepest node and its stretch along the target."""
        values, sigma = (mark.applied, mark.applied_sigma) if mark.learned else (mark.values, mark.sigma)
        if values is None:
            values, sigma = np.zeros((mark.rows, mark.size)), np.full((mark.rows, mark.size), np.inf)
        r, j = np.unravel_index(int(np.argmax(np.abs(values))), values.shape)
        nodes = self.origin_mm + self.step_mm * (mark.first + np.arange(mark.size))
        weight = np.abs(values).sum(axis=0)
        centre = float((weight @ nodes) / weight.sum()) if weight.sum() > 0 else float(nodes.mean())
        return {"x_mm": round(centre, 4), "from_mm": round(float(nodes[0]), 4), "to_mm": round(float(nodes[-1]), 4),
                "depth": round(-float(values[r, j]), 4), "depth_sigma": round(float(sigma[r, j]), 4),
                "row": int(r), "frames": mark.frames, "travel_px": round(mark.travel_px, 2),
                "chi2_dof": round(mark.chi2_dof, 3) if math.isfinite(mark.chi2_dof) else None,
                "learned_at": mark.learned_at}

    @property
    def learned(self) -> list[Mark]:
        return [mark for mark in self.marks if mark.learned]

    def summary(self) -> dict[str, Any]:
        """What a run learned: the marks (where, how deep, how sure), the candidates still open, the
        candidates refused as following the camera, and the learn/drop events."""
        return {"learned": len(self.learned), "candidates": len(self.marks) - len(self.learned),
                "refused": self.refused, "grid_step_mm": self.step_mm,
                "marks": [self.describe(mark) for mark in self.learned],
                "events": [{"frame": e.frame, "what": e.what, **e.mark} for e in self.events]}

    def line(self) -> str:
        """One sentence for a command's output."""
        return summary_line(self.summary())

    def as_target_map(self) -> dict[str, Any] | None:
        """The learned marks as a target map's fields (core/effects/target_map.py), added into the
        model's own map when it has one: what the model of record keeps. None: nothing learned."""
        learned = self.learned
        if not learned:
            return None
        model = self.model
        low = min(mark.first for mark in learned)
        high = max(mark.first + mark.size for mark in learned)
        if model.target_map is not None:
            ratio = int(round(model.target_map_step_mm / self.step_mm))
            base_first = int(round((model.target_map_origin_mm - self.origin_mm) / self.step_mm))
            low, high = min(low, base_first), max(high, base_first + ratio * (model.target_map.shape[1] - 1) + 1)
        nodes = self.origin_mm + self.step_mm * np.arange(low, high)
        table = np.zeros((self.rows, nodes.size))
        if model.target_map is not None:
            position = (nodes - model.target_map_origin_mm) / model.target_map_step_mm
            rows = np.arange(model.target_map.shape[0])[:, None]
            table += map_lookup(model.target_map, rows, np.broadcast_to(position, (rows.size, nodes.size)))[0] - 1.0
        for mark in learned:
            table[:, mark.first - low:mark.first - low + mark.size] += mark.applied
        return {"target_map": table, "target_map_origin_mm": float(nodes[0]), "target_map_step_mm": self.step_mm}


def summary_line(summary: dict[str, Any] | None) -> str:
    """One sentence from :meth:`Texture.summary` (None: not learning)."""
    if summary is None:
        return "texture: not learned (off)"
    marks = summary.get("marks") or []
    pending = f", {summary.get('candidates', 0)} candidate(s) open" if summary.get("candidates") else ""
    if not marks:
        return f"texture: nothing learned on the print{pending}"
    deepest = max(marks, key=lambda mark: abs(mark["depth"]))
    where = ", ".join(f"{mark['x_mm']:.3f}" for mark in marks[:8]) + (" …" if len(marks) > 8 else "")
    return (f"texture: {len(marks)} mark(s) learned on the print at x_w = {where} mm (deepest "
            f"{100 * deepest['depth']:.1f} % ± {100 * deepest['depth_sigma']:.1f} % of the light){pending}; "
            "their samples count again")
