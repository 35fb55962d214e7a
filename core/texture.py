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

A learned mark's samples count again. Each frame that sees one is solved first with every learned
mark's samples set aside (the print alone places it), the marks are divided out there, and each
corrected sample's variance grows by its mark's: the fit's σ (its covariance, scaled node by node by
the spread of the samples about it), that spread itself, and the mark's slope times the position's
uncertainty (a speck's edge is some 70x steeper than the paper print: read a micrometre off, it
would pull the frame harder than the print holds it). A mark is refined by every frame that sees
it; one more dust lands on is relearnt (its samples set aside meanwhile), one that stops fitting
(blown off the print) is dropped. The marks also tell the pixels' footprint on the print, which a
model may carry off the rig's (core/texture_mark.py). Steady runs open a candidate only where a
frame sets samples aside and learn nothing (the false-learning rate: docs/robustness.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from graytrack.core.effects.target_map import MAX_MAP_STEPS
from graytrack.core.frame_kernel import CUT_SIGMA
from graytrack.core.models.fourier import FourierModel
from graytrack.core.solvers import FrameSolution, GeneralBatch, TrigPolyBatch, robust_solve
from graytrack.core.texture_mark import FIELDS, Grid, Mark, scale_chi2
from graytrack.core.texture_shape import shape_vouches

STEPS_PER_PIXEL = MAX_MAP_STEPS  # a quarter of a pixel footprint: specks narrower than a pixel keep their shape
MARGIN_PX = 1.5  # a candidate's stretch beyond the samples set aside (a speck's faint tails)
MAX_SPAN_PX = 16.0  # wider than this: not a mark (a shadow, the light), left to the light's solve
MIN_FRAMES = 10  # frames that saw a candidate before it may be learned
MIN_TRAVEL_PX = 1.5  # pixels the print moved under it: every node seen by two pixels, a pixel's defect shown up
SIGNIFICANT_Z = 6.0  # its deepest node this many of its own σ from 0
MOVES_CHI2 = 25.0  # χ² by which fixed-to-the-print beats fixed-to-the-pixels (5σ)
GIVE_UP_TRAVEL_PX = 8.0  # a candidate not learned after the print moved this far under it: dropped
GIVE_UP_FRAMES = 400  # ... or after this many frames that saw it (a stage standing still)
MAX_CANDIDATES = 64  # open candidates at most (the oldest dropped first)
REFIT_EVERY = 5  # frames that saw a mark between two fits of it
REFUSED_FRAMES = 100  # pixels whose candidate followed the camera open none for this long
GRATING_WINDOW = 20  # frames the camera's offset from the grating is averaged over (it follows a latency's v·Δt)
GRATING_AGREES_PX = 0.1  # the grating vouches for a frame's place only within this of the frame's own
SCALE_EVERY = 50  # frames between two searches of the pixels' footprint on the print (from the marks learned)
SCALE_EVERY_LONGEST = 800  # ... up to this, while the marks keep agreeing with the footprint found
SCALE_TRAVEL_PX = 10.0  # marks seen over this much travel say what the footprint is
SCALE_RANGE = 0.03  # the footprint searched within this of the model's (relative)
SCALE_CHI2 = 25.0  # a footprint the marks prefer by this much χ² (5σ) is taken
UNVOUCHED_SHARE = 0.1  # a mark more of whose frames' places nothing vouched for: held (its frames flagged)
PULL_Z = 4.0  # a frame the learned marks move this many σ of the move from where the print alone places it: flagged
CHANGED_FRAMES = 3  # frames in a row with samples beyond a learned mark's cut: it changed (more dust landed on it)
STATE_VERSION = 1  # of :meth:`Texture.state`'s document


@dataclass
class TextureEvent:
    frame: int
    what: str  # "learned", "changed", "dropped" or "footprint"
    mark: dict[str, Any]


class Texture:
    """The marks learned on the print in one run (and the candidates on their way), for one model.

    ``corrected`` gives the frame to solve (its learned marks divided out, their samples weighted
    by the marks' uncertainty); ``observe`` takes the solved frame's evidence. Both cost nothing
    while there is no mark and no sample is set aside."""

    def __init__(self, model: FourierModel, max_set_aside: float = 1.0):
        """``max_set_aside``: the share of a frame's samples the tracker trusts a frame without (the
        samples of marks relearning are set aside only within it)."""
        self.model = model
        self.max_set_aside = max_set_aside
        step = model.pixel_pitch_mm / STEPS_PER_PIXEL
        # on the grid of the model's own target map when it has one (a learned mark is what it would hold)
        origin = float(model.target_map_origin_mm) if model.target_map is not None else 0.0
        if model.target_map is not None:
            ratio = model.target_map_step_mm / step
            if abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1:
                step = model.target_map_step_mm / round(ratio)
        self.grid = Grid(origin, step)
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
        self.opened = 0  # candidates opened over the run
        self.corrected_px = 0  # samples the last frame had corrected by a learned mark
        self.alone_mm, self.alone_var = math.nan, math.nan  # where the print alone placed the last frame, its σ²
        self.pull_z = 0.0  # how far the marks moved the last frame from there, in σ of the move
        self.held_px = 0  # of the samples corrected, those of held marks (learned from places nothing vouched for)
        self.grating_offset_mm, self.grating_frames = 0.0, 0  # the camera's recent mean offset from the grating
        self.scaled_at = 0  # frame of the last search of the footprint
        self.scale_every = SCALE_EVERY  # frames to the next one (doubled each time a search keeps the footprint)

    # ------------------------------------------------------------------ the frame to solve
    def corrected(self, tracker, batch: GeneralBatch | TrigPolyBatch, k: int, x_guess: float,
                  free: bool, gain: float, offset: float) -> tuple[GeneralBatch | TrigPolyBatch, int]:
        """Batch frame ``k`` with the learned marks in view divided out, as a one-frame batch (or the
        batch itself when no mark is in view).

        The marks are read where the print alone places the frame: solved first with every sample
        of a mark set aside (near the predicted position), then divided out there. A mark's edge is
        far steeper than the print (a speck's edge darkens the light by 25 % over 20 µm, the print's
        fundamental by 1 % over 20 µm): read a micrometre off, it would pull the frame harder than
        the print holds it, so each corrected sample also carries the variance of its mark read at
        an uncertain place, (y·m′·σ_x)², and an edge counts for little while a speck's flat middle
        gives the print's information back."""
        self.corrected_px, self.alone_mm, self.alone_var, self.pull_z, self.held_px = 0, math.nan, math.nan, 0.0, 0
        if not math.isfinite(x_guess) or not any(mark.learned for mark in self.marks):
            return batch, k
        y, w = batch.frames[k], batch.weights(k)
        under = self._under_marks(x_guess)
        if under is None:
            return batch, k
        start = FrameSolution(x_guess, float("nan"), 0.0, 0, gain, offset)
        alone = robust_solve(self._batch(tracker, y, np.where(under, 0.0, w)), 0, start, free, tracker.settings, None,
                             tracker.chi2_limit, tracker.layout)
        placed = math.isfinite(alone.x_mm) and abs(alone.x_mm - x_guess) < self.model.pixel_pitch_mm \
            and alone.information > 0.0
        x_at = alone.x_mm if placed else x_guess
        sigma_x = 1.0 / math.sqrt(alone.information) if placed else self.model.pixel_pitch_mm
        divided = self._divided(y, w, x_at, sigma_x)
        if divided is None:
            return batch, k
        self.corrected_px, self.held_px = int(divided[2]), int(divided[3])
        if placed:
            self.alone_mm, self.alone_var = alone.x_mm, 1.0 / alone.information
        return self._batch(tracker, divided[0], divided[1]), 0

    def pulls(self, solution: FrameSolution) -> bool:
        """The frame's answer rests on learned marks nothing vouched for: a held mark corrected it
        (learned from frames whose places neither the grating nor their own fit vouched for, see
        :meth:`_judge`), or the marks moved it from where the print alone places it (their samples
        set aside) by more than ``PULL_Z`` σ of that move: the marks, not the print, hold its position.

        The print alone and the corrected frame are nested estimates (the corrected one holds the
        same samples and the marks' too), so their difference has the variance σ_alone² − σ_corrected².
        A mark learned right adds information near where the print alone places the frame; a mark
        learned from positions something pulled (a smudge's wings, without a grating to vouch for
        them) holds the frames where they were pulled, with χ² at its level: that frame is flagged."""
        if self.corrected_px and math.isfinite(self.alone_mm) and math.isfinite(solution.x_mm) \
                and solution.information > 0.0:
            corrected_var = 1.0 / solution.information
            variance = max(self.alone_var - corrected_var, 0.1 * corrected_var)
            self.pull_z = (solution.x_mm - self.alone_mm) / math.sqrt(variance)
        return self.held_px > 0 or self.pull_z_beyond

    @property
    def pull_z_beyond(self) -> bool:
        """The last frame's marks moved it beyond ``PULL_Z`` σ from where the print alone places it."""
        return abs(self.pull_z) > PULL_Z

    def _under_marks(self, x_mm: float) -> np.ndarray | None:
        """Samples on any mark's stretch at ``x_mm`` (None: none)."""
        under = np.zeros(self.offsets.size, dtype=bool)
        for mark in self.learned:
            where = self._inside(mark, x_mm)
            if where is not None:
                under[where[0]] = True
        return under if under.any() else None

    def _divided(self, y: np.ndarray, w: np.ndarray, x_mm: float, sigma_x_mm: float):
        """(y / (1 + m), its weights, samples corrected, of them by held marks) at position ``x_mm``
        known to ``sigma_x_mm``; None: no mark in view. The samples of a candidate in view are set
        aside (a speck just landed pulls the position with the tails the robust solve leaves in, until
        it is learned), and so are those of a mark relearning. A corrected sample's variance: its
        noise's, the share of it the mark's fit left unexplained there (its misfit), and the mark's
        own uncertainty and its slope times the position's, times the light it darkens."""
        factor, variance, misfit = np.ones_like(y), np.zeros_like(y), np.zeros_like(y)
        touched, held, pending = 0, 0, np.zeros(y.shape, dtype=bool)
        for mark in self.marks:
            where = self._inside(mark, x_mm)
            if where is None:
                continue
            samples, cell, frac = where
            if not mark.learned:
                continue  # a candidate's samples are the robust solve's business, as any other's
            if mark.relearning:  # its correction is wrong where more landed: its samples wait until relearnt
                pending[samples] = True
                continue
            rows = self.row_of[samples]

            def read(table: np.ndarray) -> np.ndarray:
                return table[rows, cell] * (1.0 - frac) + table[rows, cell + 1] * frac

            applied, applied_sigma, applied_misfit = mark.correction()
            slope = (applied[rows, cell + 1] - applied[rows, cell]) / self.grid.step_mm
            factor[samples] *= 1.0 + read(applied)
            variance[samples] += read(np.square(applied_sigma)) + np.square(slope * sigma_x_mm)
            misfit[samples] += read(applied_misfit)
            touched += samples.size
            held += samples.size if mark.held else 0
        if pending.mean() > self.max_set_aside:  # more than a frame may lose: left to the robust solve, which
            pending[:] = False  # refuses such a frame rather than place it on what is left
        if not touched and not pending.any():
            return None
        factor = np.maximum(factor, 0.05)  # a mark never darkens a sample to nothing
        w = np.where(pending, 0.0, w)
        corrected = y / factor
        with np.errstate(divide="ignore", invalid="ignore"):
            noise = np.where(w > 0.0, (1.0 + misfit) / np.where(w > 0.0, w, 1.0) / (factor * factor), np.inf)
            weights = np.where(w > 0.0, 1.0 / (noise + corrected * corrected * variance), 0.0)
        return corrected, np.nan_to_num(weights, nan=0.0, posinf=0.0), touched, held

    @staticmethod
    def _batch(tracker, frame: np.ndarray, weights: np.ndarray):
        if tracker.fast_path:
            return TrigPolyBatch(tracker.tables, frame[None], weights[None], evaluator=tracker.evaluator)
        return GeneralBatch.one(tracker.evaluator, frame[None].copy(), weights[None])

    def _inside(self, mark: Mark, x_mm: float):
        """Samples whose target coordinate at ``x_mm`` lies on the mark's stretch: (samples, cell, frac)."""
        grid = self.grid
        lo = grid.origin_mm + grid.step_mm * mark.first
        hi = lo + grid.step_mm * (mark.size - 1)
        if x_mm + grid.scale * self.view_mm[1] < lo or x_mm + grid.scale * self.view_mm[0] >= hi:
            return None
        position = grid.position(x_mm, self.offsets, mark.first)
        samples = np.flatnonzero((position >= 0.0) & (position < mark.size - 1))
        if not samples.size:
            return None
        cell = np.floor(position[samples]).astype(np.int64)
        return samples, cell, position[samples] - cell

    # ------------------------------------------------------------------ evidence
    def observe(self, tracker, batch: GeneralBatch | TrigPolyBatch, k: int, solution: FrameSolution,
                placed: bool, frame: int, reference_mm: float = math.nan, trusted: bool = True) -> None:
        """Add frame ``k``'s residual (the frame as recorded, at its solution) to every mark it sees;
        open candidates where it set samples aside; learn, refine or drop marks. A frame not placed
        only for the share of its samples set aside (the marks not learned yet) still tells them:
        the samples kept fit, and without it a print dusty enough to lose frames is never learned."""
        fits = solution.rms_gray <= tracker.residual_limit_gray and solution.iterations > 0
        if not math.isfinite(solution.x_mm) or not (placed or fits):
            return
        x = self._vouched(solution.x_mm, reference_mm, placed)
        vouched = trusted or x != solution.x_mm  # the grating's reading, or a frame the tracker trusts
        set_aside = solution.rejected_px > 0 or solution.transient_px > 0
        in_view = [mark for mark in self.marks if self._inside(mark, x) is not None]
        if not set_aside and not in_view:
            return
        values = tracker.evaluator.evaluate(np.array([x]))[0][0]
        scale = solution.gain * values + solution.offset_gray  # what the frame would show without the marks
        y, w = batch.frames[k], batch.weights(k)
        residual = y - scale
        for mark in in_view:
            self._add(mark, x, residual, scale, w, frame, vouched)
        if set_aside:
            self._open(x, residual, w, solution, frame)
        self._review(frame)

    def _vouched(self, x_mm: float, reference_mm: float, placed: bool) -> float:
        """Where the frame saw the print, for the marks' evidence: the grating's reading in the
        camera's frame of reference (the camera's recent mean offset from it added) where the grating
        is read and agrees, else the frame's own position. The grating's reading is far less noisy
        than one frame's position; a mark learned from the frames' own positions would be smeared by
        their scatter, and would pull the next frames towards where the last ones were placed."""
        if not math.isfinite(reference_mm):
            return x_mm
        if placed:
            self.grating_frames = min(self.grating_frames + 1, GRATING_WINDOW)
            self.grating_offset_mm += (x_mm - reference_mm - self.grating_offset_mm) / self.grating_frames
        vouched = reference_mm + self.grating_offset_mm
        agrees = abs(vouched - x_mm) < GRATING_AGREES_PX * self.model.pixel_pitch_mm
        return vouched if self.grating_frames >= GRATING_WINDOW // 2 and agrees else x_mm

    def _add(self, mark: Mark, x: float, residual: np.ndarray, scale: np.ndarray, w: np.ndarray, frame: int,
             vouched: bool = True) -> None:
        """The frame's samples on the mark's stretch as its evidence, unless they depart from the
        learned mark (a glint on top of it); samples departing frame after frame: it changed."""
        samples, cell, frac = self._inside(mark, x)
        weights, r, a = w[samples], residual[samples], scale[samples]
        keep = weights > 0.0
        if mark.learned and not mark.relearning:
            rows = self.row_of[samples]
            applied, spread, _ = mark.correction()
            predicted = a * (applied[rows, cell] * (1.0 - frac) + applied[rows, cell + 1] * frac)
            allowance = np.abs(a) * np.maximum(spread[rows, cell], spread[rows, cell + 1])
            inside = np.abs(r - predicted) <= CUT_SIGMA * np.sqrt(1.0 / np.maximum(weights, 1e-300) + allowance**2)
            mark.outlying = mark.outlying + 1 if (keep & ~inside).any() else 0
            if mark.outlying >= CHANGED_FRAMES:  # the same stretch departs frame after frame: the mark changed
                self.events.append(TextureEvent(frame, "changed", self.describe(mark)))
                mark.reset()  # fresh evidence from here on; the old m goes on correcting until it is ready
                mark.relearning = True
            else:
                keep &= inside
        samples, weights, r, a = samples[keep], weights[keep], r[keep], a[keep]
        if not samples.size:
            return
        part = np.stack(np.broadcast_arrays(x, self.offsets[samples], self.row_of[samples],
                                            self.column_of[samples] + self.n_pixels * self.row_of[samples], r, a,
                                            weights)).astype(np.float64)
        grid = self.grid
        centre = (grid.origin_mm + grid.step_mm * (mark.first + 0.5 * (mark.size - 1)) - x) / (
            grid.scale * self.model.pixel_pitch_mm)
        mark.add(part, centre, frame, vouched)

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
            lo = x + self.grid.scale * centre_row[start] - MARGIN_PX * pitch - self._row_reach()
            hi = x + self.grid.scale * centre_row[stop - 1] + MARGIN_PX * pitch + self._row_reach()
            first = int(math.floor((lo - self.grid.origin_mm) / self.grid.step_mm))
            last = int(math.ceil((hi - self.grid.origin_mm) / self.grid.step_mm))
            for start_node, stop_node in self._outside_learned(first, last):
                self._candidate(start_node, stop_node, frame)

    def _outside_learned(self, first: int, last: int) -> list[tuple[int, int]]:
        """The parts of nodes ``first..last`` no learned mark holds (a learned mark keeps its stretch:
        what lands on it, it relearns), at least three nodes long."""
        pieces = [(first, last)]
        for mark in self.learned:
            end = mark.last
            pieces = [part for low, high in pieces
                      for part in ((low, min(high, mark.first)), (max(low, end), high)) if part[1] > part[0]]
        return [(low, high) for low, high in pieces if high - low >= 2]

    def _candidate(self, first: int, last: int, frame: int) -> None:
        """A candidate on nodes ``first..last``, grown into the candidates it meets."""
        overlapping = [m for m in self.marks if not m.learned and m.first <= last and first <= m.last]
        if overlapping:
            keep = overlapping[0]
            for other in overlapping[1:]:  # grown together: the older one holds the stretch
                keep.extend(other.first, other.last)
                self.marks.remove(other)
            keep.extend(first, last)
            if keep.size * self.grid.step_mm > MAX_SPAN_PX * self.model.pixel_pitch_mm:
                self.marks.remove(keep)
            return
        if len(self.marks) >= MAX_CANDIDATES:
            oldest = next((m for m in self.marks if not m.learned), None)
            if oldest is None:
                return
            self.marks.remove(oldest)
        self.marks.append(Mark(first, last - first + 1, self.rows, frame, last_seen=frame))
        self.opened += 1

    def _row_reach(self) -> float:
        """How far the rows' views of one point differ along the target (a tilted strip)."""
        offsets = self.offsets.reshape(self.rows, self.n_pixels)[:, 0]
        return float(offsets.max() - offsets.min()) / 2.0

    def _review(self, frame: int) -> None:
        """Refit the marks that saw enough new frames; learn the candidates that are ready, drop the
        hopeless ones and the learned ones that stopped fitting; now and then, the footprint."""
        if frame - self.scaled_at >= self.scale_every:
            self._rescale(frame)
        for mark in list(self.marks):
            # a learned mark's fit moves less with each frame: refitted after a tenth more of them; a mark
            # restored from a saved state keeps its saved fit until fresh evidence outweighs it
            every = max(REFIT_EVERY, mark.frames // 10) if mark.learned else REFIT_EVERY
            due = mark.since_fit >= every or (not mark.learned and mark.frames >= MIN_FRAMES and mark.since_fit)
            due = due and (mark.relearning or mark.frames >= mark.seen_before)
            if due and mark.frames:
                self._judge(mark, mark.refit(self.grid), frame)
            if mark not in self.marks:
                continue
            hopeless = mark.travel_px > GIVE_UP_TRAVEL_PX or mark.frames > GIVE_UP_FRAMES
            if mark.learned:
                if mark.relearning and hopeless:
                    self.marks.remove(mark)  # what landed on it cannot be told apart: it is no mark any more
                    self.events.append(TextureEvent(frame, "dropped", self.describe(mark)))
            elif hopeless:
                self.marks.remove(mark)
                if mark.fit is not None and mark.fit.moves_chi2 < 0.0:  # it followed the camera: a pixel's defect
                    self._refuse(mark, frame)
            elif frame - mark.last_seen > GIVE_UP_FRAMES:
                self.marks.remove(mark)

    def _judge(self, mark: Mark, fit, frame: int) -> None:
        """A fresh fit: a learned mark is refined by it (or dropped when the frames stop agreeing);
        a candidate (or a mark relearning) that is ready is learned."""
        if mark.learned and not mark.relearning:
            if fit.consistent():
                mark.apply(fit)
                mark.held = self._held(mark)
            else:
                self.marks.remove(mark)
                self.events.append(TextureEvent(frame, "dropped", self.describe(mark)))
        elif (mark.frames >= MIN_FRAMES and mark.travel_px >= MIN_TRAVEL_PX and fit.consistent()
              and fit.moves_chi2 > MOVES_CHI2 and fit.peak_z > SIGNIFICANT_Z):
            mark.apply(fit)
            mark.relearning = False
            mark.held = self._held(mark)
            mark.learned_at = frame
            self.events.append(TextureEvent(frame, "learned", self.describe(mark)))

    def _held(self, mark: Mark) -> bool:
        """More than ``UNVOUCHED_SHARE`` of the mark's frames had places nothing vouched for, and its own
        shape does not vouch for it either (a speck's dip, narrow and whole: core/texture_shape.py)."""
        step_px = self.grid.step_mm / self.model.pixel_pitch_mm
        return mark.unvouched > UNVOUCHED_SHARE * mark.frames and not shape_vouches(mark, self.learned, step_px)

    def _rescale(self, frame: int) -> None:
        """The pixels' footprint on the print, from the learned marks seen over a long travel: the
        scale at which their frames agree best (a coarse then a fine search), taken when it beats the
        present one by ``SCALE_CHI2``; every mark is then moved and refitted at it."""
        self.scaled_at = frame
        telling = [mark for mark in self.learned if mark.travel_px >= SCALE_TRAVEL_PX]
        if not telling:
            return
        grid = self.grid
        now = scale_chi2(telling, grid, grid.scale)
        best, best_chi2 = grid.scale, now
        for spacing in (SCALE_RANGE / 6.0, SCALE_RANGE / 60.0):
            centre = best
            for scale in centre * (1.0 + spacing * np.arange(-6, 7)):
                chi2 = scale_chi2(telling, grid, float(scale))
                if chi2 < best_chi2:
                    best, best_chi2 = float(scale), chi2
        if now - best_chi2 < SCALE_CHI2:
            self.scale_every = min(2 * self.scale_every, SCALE_EVERY_LONGEST)
            return
        self.scale_every = SCALE_EVERY
        for mark in self.marks:
            mark.shift(int(round((best - grid.scale) * mark.centre_offset() / grid.step_mm)))
        grid.scale = best
        self.events.append(TextureEvent(frame, "footprint", {"scale": round(best, 5),
                                                             "chi2_gain": round(now - best_chi2, 1)}))
        for mark in list(self.marks):
            if mark.frames:
                self._judge(mark, mark.refit(grid), frame)

    def _refuse(self, mark: Mark, frame: int) -> None:
        """The pixels that carried a candidate's residual open no candidate for a while."""
        samples = mark.samples()
        pixels = samples[FIELDS.index("pixel")].astype(np.int64)
        weight, scale, residual = (samples[FIELDS.index(name)] for name in ("weight", "scale", "residual"))
        aa = np.bincount(pixels, weight * scale * scale)
        ar = np.bincount(pixels, weight * scale * residual)
        worst = int(np.argmax(np.where(aa > 0, np.abs(ar) / np.sqrt(np.maximum(aa, 1e-300)), 0.0)))
        column = worst % self.n_pixels
        self.refused_until[max(column - 1, 0):column + 2] = frame + REFUSED_FRAMES
        self.refused += 1

    # ------------------------------------------------------------------ what was learned
    def describe(self, mark: Mark) -> dict[str, Any]:
        """Where a mark is, how deep, how sure: its deepest node and its stretch along the target."""
        fit = mark.fit
        if mark.learned:
            values, sigma, _ = mark.correction()
        elif fit is not None:
            values, sigma = fit.values, fit.sigma
        else:
            values, sigma = np.zeros((mark.rows, mark.size)), np.full((mark.rows, mark.size), np.inf)
        # the deepest node its evidence stands for (two of its σ): a node at the mark's edge seen on few frames
        # can be deeper by its noise alone (a daemon's mark read 43 % ± 49 %)
        depth = np.abs(values)
        standing = depth >= 2.0 * sigma
        r, j = np.unravel_index(int(np.argmax(np.where(standing, depth, -np.inf) if standing.any()
                                              else depth / np.maximum(sigma, 1e-300))), values.shape)
        grid = self.grid
        nodes = grid.origin_mm + grid.step_mm * (mark.first + np.arange(mark.size))
        weight = np.abs(values).sum(axis=0)
        centre = float((weight @ nodes) / weight.sum()) if weight.sum() > 0 else float(nodes.mean())
        return {"x_mm": round(centre, 4), "from_mm": round(float(nodes[0]), 4), "to_mm": round(float(nodes[-1]), 4),
                "depth": round(-float(values[r, j]), 4), "depth_sigma": round(float(sigma[r, j]), 4),
                "row": int(r), "frames": max(mark.frames, mark.seen_before),
                "travel_px": round(float(mark.travel_px), 2),
                "chi2_dof": round(fit.chi2_dof, 3) if fit is not None else None, "learned_at": mark.learned_at,
                "unvouched": round(mark.unvouched / max(mark.frames, 1), 3), "held": mark.held}

    @property
    def learned(self) -> list[Mark]:
        return [mark for mark in self.marks if mark.learned]

    def summary(self) -> dict[str, Any]:
        """What a run learned: the marks (where, how deep, how sure), the candidates still open, the
        candidates refused as following the camera, and the learn/drop events."""
        return {"learned": len(self.learned), "candidates": len(self.marks) - len(self.learned),
                "opened": self.opened, "refused": self.refused, "grid_step_mm": self.grid.step_mm,
                "footprint_scale": self.grid.scale,
                "marks": [self.describe(mark) for mark in self.learned],
                "events": [{"frame": e.frame, "what": e.what, **e.mark} for e in self.events]}

    def line(self) -> str:
        """One sentence for a command's output."""
        return summary_line(self.summary())

    # ------------------------------------------------------------------ kept between runs
    def state(self) -> dict[str, Any]:
        """The learned marks and the footprint as a JSON document (what the daemon keeps with its model
        of record; ``from_state`` reads it back). Candidates and evidence stay with the run: a mark is
        kept as its fit (the relative reflectance per node, its σ and misfit), not as the thousands of
        samples behind it, and a mark restored from it corrects frames with that fit until as many
        fresh frames have seen it."""
        grid = self.grid
        return {"version": STATE_VERSION, "rows": self.rows, "pixels": self.n_pixels,
                "grid": {"origin_mm": grid.origin_mm, "step_mm": grid.step_mm, "scale": grid.scale},
                "marks": [_mark_state(mark, self.describe(mark)) for mark in self.learned]}

    @classmethod
    def from_state(cls, model: FourierModel, state: dict[str, Any], max_set_aside: float = 1.0) -> "Texture":
        """A texture for ``model`` holding the marks of ``state`` (:meth:`state`); ValueError when the
        document is not one, or was written for another model's grid (its marks would sit elsewhere)."""
        texture = cls(model, max_set_aside)
        try:
            if state.get("version") != STATE_VERSION:
                raise ValueError(f"version {state.get('version')!r}, not {STATE_VERSION}")
            grid, ours = state["grid"], texture.grid
            if (int(state["rows"]), int(state["pixels"])) != (texture.rows, texture.n_pixels):
                raise ValueError(f"{state['rows']} x {state['pixels']} pixels, the model has "
                                 f"{texture.rows} x {texture.n_pixels}")
            if not (math.isclose(float(grid["origin_mm"]), ours.origin_mm, abs_tol=1e-12)
                    and math.isclose(float(grid["step_mm"]), ours.step_mm, rel_tol=1e-9)):
                raise ValueError("its grid is not this model's")
            scale = float(grid["scale"])
            if not (math.isfinite(scale) and abs(scale - 1.0) <= 2 * SCALE_RANGE):
                raise ValueError(f"footprint scale {scale!r}")
            texture.grid.scale = scale
            texture.marks = [_mark_of(item, texture.rows) for item in state["marks"]]
        except (KeyError, TypeError, IndexError) as exc:
            raise ValueError(f"not a texture state ({type(exc).__name__}: {exc})") from None
        return texture


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


def _table(values: np.ndarray) -> list[list[float | None]]:
    """A node table as JSON (∞, a node no frame saw, as null)."""
    return [[float(v) if math.isfinite(v) else None for v in row] for row in np.asarray(values, dtype=np.float64)]


def _array(rows: Any, shape: tuple[int, int], what: str) -> np.ndarray:
    table = np.array([[np.inf if v is None else float(v) for v in row] for row in rows], dtype=np.float64)
    if table.shape != shape:
        raise ValueError(f"{what}: shape {table.shape}, not {shape}")
    return table


def _mark_state(mark: Mark, description: dict[str, Any]) -> dict[str, Any]:
    """One learned mark as JSON: where (its nodes), its fit, and what :meth:`Texture.describe` says of it."""
    m, sigma, misfit = mark.correction()
    return {"first": mark.first, "size": mark.size, "learned_at": mark.learned_at, "relearning": mark.relearning,
            "frames": max(mark.frames, mark.seen_before), "held": mark.held, "m": _table(m),
            "sigma": _table(sigma), "misfit": _table(misfit), "describe": description}


def _mark_of(item: dict[str, Any], rows: int) -> Mark:
    """A learned mark back from :func:`_mark_state` (its evidence empty: fresh frames gather it)."""
    size = int(item["size"])
    if size < 2:
        raise ValueError(f"a mark of {size} node(s)")
    shape = (rows, size)
    mark = Mark(int(item["first"]), size, rows, opened=-1, learned_at=int(item["learned_at"]),
                relearning=bool(item["relearning"]))
    values, sigma, misfit = (_array(item[key], shape, key) for key in ("m", "sigma", "misfit"))
    if not (np.isfinite(values).all() and np.isfinite(misfit).all() and (sigma > 0).all()):
        raise ValueError("a mark's fit has non-finite values")
    mark.applied, mark.applied_sigma, mark.applied_misfit = values, sigma, misfit
    mark.held = bool(item.get("held", False))  # learned from places nothing vouched for: its frames stay flagged
    mark.seen_before = 0 if mark.relearning else int(item["frames"])
    return mark
