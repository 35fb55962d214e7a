"""One mark on the print, learned from the frames that saw it (core/texture.py decides what to do
with it): its evidence, kept sample by sample, and its fit as a relative reflectance on the target
map's grid (core/effects/target_map.py: piecewise linear in the target coordinate, a row for each
model row).

The evidence is kept as the samples themselves (a few thousand numbers for a mark seen on a few
hundred frames), not as folded normal equations, because where a pixel looks on the print is only
known up to the pixel footprint's scale: a model calibrated on the paper rig carries α·d 0.8 % off
the rig's (its per-pixel coefficients absorb the difference, the print's phase is all it needs),
which moves a mark seen at pixel 90 and again at pixel 30 by 30 µm on the print, half a speck. The
texture finds that scale from the marks (:func:`scale_chi2`), and the marks are fitted again at it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

CONSISTENT_SPREADS = 5.0  # χ² within this many of its spreads of its degrees of freedom ...
# ... plus this share of the mark's own signal (Σ w r²): the grid's misfit of a speck's shape (a
# quarter-pixel hat basis leaves a few % of a sharp speck's edges). A glint that came and went, a
# pixel gone bad seen by the print's other pixels, leave most of their signal unexplained.
MISFIT_SHARE = 0.1
LOCAL_PRIOR = 5.0  # samples' worth of the mark's own spread in each node's (few samples are a noisy spread)
PRIOR_SIGMA = 0.5  # a mark changes the light by less than about half: what holds a node few frames saw
FIELDS = ("x", "offset", "row", "pixel", "residual", "scale", "weight")  # a sample's evidence, in this order


@dataclass
class Grid:
    """Where the texture's nodes are: node j at ``origin_mm + j·step_mm`` of the target; a pixel
    with nominal offset ``o`` (the model's target_offset) looks at ``x + scale·o`` on a frame at x."""

    origin_mm: float
    step_mm: float
    scale: float = 1.0

    def position(self, x_mm: np.ndarray | float, offset_mm: np.ndarray, first: int) -> np.ndarray:
        """Grid position (in nodes from node ``first``) that pixels of nominal offsets look at."""
        return (x_mm + self.scale * offset_mm - self.origin_mm) / self.step_mm - first


@dataclass
class MarkFit:
    """A mark's relative reflectance per node (R, size), its standard error (∞ where no frame saw
    the node), and how well the frames agree on it."""

    values: np.ndarray
    sigma: np.ndarray
    misfit: np.ndarray  # (R, size): the samples' spread about the fit beyond their noise, in units of its variance
    chi2: float
    samples: int
    seen_nodes: int
    signal: float  # Σ w r² of the samples fitted
    moves_chi2: float  # χ² the camera-fixed alternative (a change of each pixel) leaves beyond this fit
    peak_z: float  # the deepest node the frames tell, in its own σ

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / max(self.samples - self.seen_nodes, 1)

    def consistent(self) -> bool:
        """The frames agree on one shape at one target coordinate (what is left is noise and misfit)."""
        dof = max(self.samples - self.seen_nodes, 1)
        return self.chi2 <= dof + CONSISTENT_SPREADS * math.sqrt(2.0 * dof) + MISFIT_SHARE * self.signal


@dataclass
class Mark:
    """One stretch of the target (nodes ``first``..``first + size − 1`` of the grid, every model
    row), the samples that saw it and, once fitted, its shape."""

    first: int
    size: int
    rows: int
    opened: int  # frame number that opened it
    parts: list[np.ndarray] = field(default_factory=list)  # (FIELDS, k) a frame
    frames: int = 0
    low_px: float = math.inf  # pixel columns its centre was seen at
    high_px: float = -math.inf
    last_seen: int = 0
    since_fit: int = 0
    learned_at: int = -1  # frame at which it was learned (−1: a candidate)
    relearning: bool = False  # it changed (more dust landed on it): fresh evidence gathers while the old m applies
    fit: MarkFit | None = None  # the last fit
    applied: np.ndarray | None = None  # the m frames are corrected by (the last fit that was ready; None: a candidate)
    applied_sigma: np.ndarray | None = None
    applied_misfit: np.ndarray | None = None
    outlying: int = 0  # frames in a row in which samples departed from the learned mark
    seen_before: int = 0  # frames behind its fit when it was restored from a saved state (core/texture.py)
    unvouched: int = 0  # of its frames, those whose place neither the grating nor the frame's own fit vouched for
    held: bool = False  # learned mostly from such frames: the frames it corrects are flagged (core/texture.py)

    def reset(self) -> None:
        """Forget the evidence (a mark that changed starts again on its stretch)."""
        self.parts, self.frames, self.since_fit, self.outlying, self.fit, self.unvouched = [], 0, 0, 0, None, 0
        self.low_px, self.high_px = math.inf, -math.inf

    @property
    def learned(self) -> bool:
        return self.applied is not None

    def correction(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(m, its σ, its misfit) per node of a learned mark (set together: :meth:`apply`)."""
        if self.applied is None or self.applied_sigma is None or self.applied_misfit is None:
            raise ValueError("a candidate mark has no correction yet")
        return self.applied, self.applied_sigma, self.applied_misfit

    @property
    def travel_px(self) -> float:
        return self.high_px - self.low_px if self.frames else 0.0

    @property
    def last(self) -> int:
        return self.first + self.size - 1

    def samples(self) -> np.ndarray:
        """Every sample's evidence ``(FIELDS, N)`` (the parts joined once, then kept joined)."""
        if len(self.parts) != 1:
            self.parts = [np.concatenate(self.parts, axis=1) if self.parts else np.zeros((len(FIELDS), 0))]
        return self.parts[0]

    def add(self, part: np.ndarray, centre_px: float, frame: int, vouched: bool = True) -> None:
        """One frame's samples ``(FIELDS, k)``; ``centre_px``: the pixel column its centre was at;
        ``vouched``: the frame's place was vouched for (by the grating, or by the frame's own fit)."""
        self.parts.append(part)
        self.unvouched += not vouched
        self.low_px, self.high_px = min(self.low_px, centre_px), max(self.high_px, centre_px)
        self.frames += 1
        self.since_fit += 1
        self.last_seen = frame

    def extend(self, first: int, last: int) -> None:
        """Grow the stretch to nodes ``first..last`` (the new nodes correct nothing until fitted)."""
        low, high = min(first, self.first), max(last, self.last)
        if low == self.first and high == self.last:
            return
        pad = ((0, 0), (self.first - low, high - self.last))
        if self.applied is not None and self.applied_sigma is not None and self.applied_misfit is not None:
            self.applied = np.pad(self.applied, pad)  # (the three are set together: :meth:`apply`)
            self.applied_sigma = np.pad(self.applied_sigma, pad, constant_values=PRIOR_SIGMA)
            self.applied_misfit = np.pad(self.applied_misfit, pad)
        self.first, self.size = low, high - low + 1

    def shift(self, nodes: int) -> None:
        """The stretch moved by ``nodes`` (the grid's scale changed under it)."""
        self.first += nodes

    def apply(self, fit: MarkFit) -> None:
        """Correct frames by this fit from now on."""
        self.applied, self.applied_sigma, self.applied_misfit = fit.values, fit.sigma, fit.misfit

    def refit(self, grid: Grid) -> MarkFit:
        """Fit the mark at the grid's scale and keep the fit."""
        self.fit = fit_samples(self.samples(), grid, self.first, self.size, self.rows)
        self.since_fit = 0
        return self.fit

    def centre_offset(self) -> float:
        """Mean nominal offset of the pixels that saw it (what a change of scale moves it by, per unit)."""
        offsets = self.samples()[1]
        return float(offsets.mean()) if offsets.size else 0.0


def fit_samples(samples: np.ndarray, grid: Grid, first: int, size: int, rows: int) -> MarkFit:
    """m on nodes ``first..first+size−1`` from samples ``(FIELDS, N)``: residual ≈ scale·m(x_w).

    Least squares row by row (a weak prior of ``PRIOR_SIGMA`` holds nodes no sample saw at 0); σ
    from the normal matrix's inverse, scaled node by node by the spread of the samples about the fit
    in the cells on either side (a sharp edge the grid follows less well is less sure); and the χ² a
    change of each pixel's response (fixed to the camera, not the print) would leave beyond it."""
    x, offset, row, pixel, residual, scale, weight = samples
    position = grid.position(x, offset, first)
    inside = (position >= 0.0) & (position < size - 1)
    position, row, pixel, residual, scale, weight = (v[inside] for v in (position, row, pixel, residual, scale,
                                                                          weight))
    cell = np.floor(position).astype(np.int64)
    frac = position - cell
    flat = row.astype(np.int64) * (size - 1) + cell
    left, right = scale * (1.0 - frac), scale * frac
    total = rows * (size - 1)
    ll, lr, rr, bl, br, r2, count = (np.bincount(flat, term, total).reshape(rows, size - 1) for term in (
        weight * left * left, weight * left * right, weight * right * right, weight * left * residual,
        weight * right * residual, weight * residual * residual, np.ones_like(residual)))
    diag, rhs = np.zeros((rows, size)), np.zeros((rows, size))
    diag[:, :-1] += ll
    diag[:, 1:] += rr
    rhs[:, :-1] += bl
    rhs[:, 1:] += br
    values, variance = np.zeros_like(rhs), np.full_like(rhs, np.inf)
    for r in range(rows):
        if not (diag[r] > 0.0).any():
            continue
        normal = np.diag(diag[r] + 1.0 / PRIOR_SIGMA**2) + np.diag(lr[r], 1) + np.diag(lr[r], -1)
        inverse = np.linalg.inv(normal)
        values[r] = inverse @ rhs[r]
        variance[r] = np.diag(inverse)
    low, high = values[:, :-1], values[:, 1:]
    cell_chi2 = np.maximum(r2 - 2.0 * (low * bl + high * br) + low * low * ll + 2.0 * low * high * lr
                           + high * high * rr, 0.0)
    seen = diag > 0.0
    n, seen_nodes, chi2 = int(inside.sum()), int(seen.sum()), float(cell_chi2.sum())
    dof = max(n - seen_nodes, 1)
    chi2_dof = chi2 / dof
    around, counted = np.zeros_like(rhs), np.zeros_like(rhs)
    around[:, :-1] += cell_chi2
    around[:, 1:] += cell_chi2
    counted[:, :-1] += count
    counted[:, 1:] += count
    local = (around + LOCAL_PRIOR * chi2_dof) / (counted * dof / max(n, 1) + LOCAL_PRIOR)
    sigma = np.where(seen, np.sqrt(np.maximum(variance, 0.0) * np.maximum(local, 1.0)), np.inf)
    signal = float(r2.sum())
    pixels = pixel.astype(np.int64)
    size_p = int(pixels.max()) + 1 if pixels.size else 1
    aa = np.bincount(pixels, weight * scale * scale, size_p)
    ar = np.bincount(pixels, weight * scale * residual, size_p)
    used = aa > 0.0
    pixel_chi2 = max(signal - float((ar[used] ** 2 / aa[used]).sum()), 0.0)
    moves_chi2 = pixel_chi2 - chi2 - (seen_nodes - int(used.sum()))  # each side's unknowns allowed for
    told = np.isfinite(sigma) & (sigma > 0.0) & (sigma < 0.5 * PRIOR_SIGMA)  # nodes the frames tell
    peak_z = float((np.abs(values[told]) / sigma[told]).max()) if told.any() else 0.0
    misfit = np.where(seen, np.maximum(local - 1.0, 0.0), 0.0)
    return MarkFit(values, sigma, misfit, chi2, n, seen_nodes, signal, moves_chi2, peak_z)


def scale_chi2(marks: list[Mark], grid: Grid, scale: float) -> float:
    """The marks' χ² were the pixels' footprint ``scale`` × nominal: each refitted on its stretch
    moved by the change (a sample that falls off its stretch counts one, what noise would give it)."""
    trial = Grid(grid.origin_mm, grid.step_mm, scale)
    total = 0.0
    for mark in marks:
        moved = int(round((scale - grid.scale) * mark.centre_offset() / grid.step_mm))
        fitted = fit_samples(mark.samples(), trial, mark.first + moved, mark.size, mark.rows)
        total += fitted.chi2 + (mark.samples().shape[1] - fitted.samples)
    return total
