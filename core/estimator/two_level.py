"""Pixels that read at one of two levels, switching at random: found on calibration's sweep and set aside.

A charge trap next to a pixel's photodiode (random telegraph noise) moves the pixel's dark level by a fixed step
when it captures an electron and back when it releases it, at random instants: the pixel reads at one of two
levels, staying at each for tens of milliseconds to seconds. Left in, it costs twice. The model's smooth pixel
polynomials take the pixel's mean level into their fit, and the pixels about it err by the bump that leaves. While
tracking, every flip lands in the estimator's two maps: the sensor's lets the pixel go each time it reads as
calibrated again, and the print's, a candidate beside it each time, now and then learns one flip as a mark on
the print (a node the print carried from the landing's neighbour onto the flipping pixel finds it high there).

Calibration's sweep reads every sample at both levels many times, the position pinned by the grating, so what each
sample leaves against the model is its own record (:func:`calibration_two_level`), less the line in the model's
value it holds (its own gain and dark level: the sensor's pattern, flat_field.py). A sample is two-level where
that record splits into two levels far apart against its noise (``SEPARATION_SIGMA``), each held over runs of
frames rather than single ones (a trap's dwell, not a glint's or a spike's: ``HELD_Z``), and where which level it
reads says nothing of what it sees nor of the other samples: not of the print's phase there (a clipped sample reads
low at the print's bright phase only, a gain's residual, a sine's, splits in two as well, and so does what a model
too plain for the print misses at each phase: the ideal sine's), not of the place along
the stroke (a mark on the print, a glint off it, reads at its place only), not of what the frame's other samples
leave (a change of the whole image moves every sample at once; a trap moves its own pixel).

Calibration (core/calibration.py) sets such pixels aside as bad pixels (core/effects/bad_pixels.py: weight 0 in
the fit and in tracking, named with the reason) and fits again: one pixel in a hundred is a percent of the
information, against a bias the flips put into the model and the maps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.recording import Recording

SEPARATION_SIGMA = 4.0  # σ of the sample's noise the two levels must lie apart at least: a frame's value then sits
# nearer the wrong one on under 2.3 % of the frames (the midpoint 2σ from each), while a sample's plain noise split in
# two has its halves' means 1.6σ apart
NOISE_SPREAD = 2.0  # the most each level's own spread may be of the sample's noise (a factor): a trap moves the level,
# not the noise about it (what the model's own error and the light leave at a sample adds a little); the frames a
# mark on the print darkens, each by what part of it a sample sees, spread far wider, as do the two halves of what a
# model too plain for the print misses at each phase
HELD_Z = 3.0  # σ of the count of switches independent frames would show by which a two-level sample must switch less
# (a level held over frames: a trap's dwell; a glint or a noise spike lasts a frame or a few, each a switch there
# and back)
LEAST_FRAMES = 10  # frames at the rarer level at least (fewer tell no level)
LEAST_RUNS = 5  # separate runs at the rarer level at least: fewer tell no switching (a change that came and went
# once or twice is the sensor's map's to follow)
STRETCHES = 8  # stretches of the sweep along the stroke, and bins of the model's value, in each of which a two-level
# sample reads its high level as often as over the whole sweep, and as many bins of the print's phase (within HELD_Z
# of the count, each run of the rarer level counted as one)
MIN_FRAMES = 40  # placed frames of the sweep at least (else nothing is found)
MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class TwoLevel:
    """Two-level samples: their indices in the frame as the model sees it, their ``low`` and ``high`` levels (gray,
    what the sample reads beyond the model at each), the noise about them (gray σ) and how often each switches (per
    second)."""

    samples: np.ndarray
    low: np.ndarray
    high: np.ndarray
    sigma: np.ndarray
    rate_hz: np.ndarray

    def bad_pixels(self, pixels: int) -> list[tuple[int, int, str]]:
        """Each sample as a bad pixel (row, pixel, reason) of a model with ``pixels`` samples a row."""
        return [(int(p) // pixels, int(p) % pixels,
                 f"reads at one of two levels {high - low:.1f} gray apart, {rate:.1f} switches/s")
                for p, low, high, rate in zip(self.samples.tolist(), self.low.tolist(), self.high.tolist(),
                                               self.rate_hz.tolist())]


def _independent(at_high: np.ndarray, bins: np.ndarray, run: float) -> bool:
    """Whether the frames ``at_high`` read the high level as often in each of ``bins`` (an index a frame) as over
    all, within ``HELD_Z`` of the count (its variance a binomial's times ``run``, the frames a level holds for)."""
    share = float(at_high.mean())
    for b in np.unique(bins).tolist():
        inside = bins == b
        n = int(inside.sum())
        if n < LEAST_FRAMES:
            continue
        spread = math.sqrt(n * share * (1.0 - share) * run)
        if abs(float(at_high[inside].sum()) - n * share) > HELD_Z * spread + 1.0:
            return False
    return True


def found(residual: np.ndarray, h: np.ndarray, phase: np.ndarray, t: np.ndarray,
          stretch: np.ndarray) -> TwoLevel | None:
    """The two-level samples among the columns of ``residual`` (frames × samples, gray: what each sample left
    against the model on each placed frame, in time order; ``h`` the model's value there and ``phase`` the print's
    phase it saw, in periods), ``t`` the frames' times and ``stretch`` their stretch along the stroke: None where
    none is. Each sample's noise is what its record changes by from one frame to the next (the median's σ: a trap's
    flips are a few of its frames)."""
    frames, samples = residual.shape
    if frames < MIN_FRAMES:
        return None
    # each sample's own line in the model's value taken out (its gain and dark level: the sensor's pattern's)
    together = residual.sum(axis=1)  # what the frame's samples leave together
    noise = MAD_TO_SIGMA * np.median(np.abs(np.diff(residual, axis=0)), axis=0) / math.sqrt(2.0)
    mean_h, mean_r = h.mean(axis=0), residual.mean(axis=0)
    dh = h - mean_h
    slope = (dh * (residual - mean_r)).sum(axis=0) / np.maximum((dh * dh).sum(axis=0), 1e-12)
    residual = residual - mean_r - slope * dh
    kept: list[tuple[int, float, float, float, float]] = []
    ordered = np.sort(residual, axis=0)
    duration = float(t[-1] - t[0]) if frames > 1 else 0.0
    for p in range(samples):
        values = ordered[:, p]
        if not np.all(np.isfinite(values)):
            continue
        # the split of the sorted values into a low and a high part with the least variance within them
        total = np.cumsum(values)
        square = np.cumsum(values * values)
        n_low = np.arange(1, frames)
        low_sum, high_sum = total[:-1], total[-1] - total[:-1]
        within = (square[:-1] - low_sum ** 2 / n_low) + (square[-1] - square[:-1] - high_sum ** 2 / (frames - n_low))
        split = int(np.argmin(within)) + 1
        rarer = min(split, frames - split)
        if rarer < LEAST_FRAMES:
            continue
        low, high = float(total[split - 1] / split), float((total[-1] - total[split - 1]) / (frames - split))
        sigma = math.sqrt(max(float(within[split - 1]) / (frames - 2), 1e-12))
        if high - low < SEPARATION_SIGMA * sigma:
            continue
        if max(float(np.std(values[:split])), float(np.std(values[split:]))) > NOISE_SPREAD * float(noise[p]):
            continue
        at_high = residual[:, p] > 0.5 * (low + high)
        # held over frames: fewer switches than independent frames at these shares would make, beyond chance
        share = float(at_high.mean())
        switches = int(np.count_nonzero(at_high[1:] != at_high[:-1]))
        independent = 2.0 * (frames - 1) * share * (1.0 - share)
        if not switches < independent - HELD_Z * math.sqrt(independent):
            continue
        # switching: the rarer level read in runs enough; which level says nothing of the place along the stroke, the
        # model's value there or what the frame's other samples leave
        rarer_level = at_high if share <= 0.5 else ~at_high
        runs = int(np.count_nonzero(rarer_level[1:] & ~rarer_level[:-1])) + int(rarer_level[0])
        if runs < LEAST_RUNS:
            continue
        run = float(rarer_level.sum()) / runs
        phase_bins = np.minimum((np.mod(phase[:, p], 1.0) * STRETCHES).astype(np.int64), STRETCHES - 1)
        if not all(_independent(at_high, bins, run) for bins in (stretch, phase_bins)):
            continue
        # the other samples leave the same at either level (each run of the rarer level one reading of it)
        others = (together - residual[:, p]) / max(samples - 1, 1)
        high_others, low_others = others[at_high], others[~at_high]
        apart = float(high_others.mean() - low_others.mean())
        spread = math.sqrt((float(high_others.var()) * high_others.size + float(low_others.var()) * low_others.size)
                           / frames)
        if abs(apart) > HELD_Z * spread * math.sqrt(run * (1.0 / high_others.size + 1.0 / low_others.size)):
            continue
        # (the levels about the sample's own line: what it reads beyond the model at each, at its mean value)
        kept.append((p, low + float(mean_r[p]), high + float(mean_r[p]), sigma,
                     switches / duration if duration > 0.0 else 0.0))
    if not kept:
        return None
    columns = [np.array(column) for column in zip(*kept)]
    return TwoLevel(columns[0].astype(np.int64), columns[1], columns[2], columns[3], columns[4])


def calibration_two_level(model: "FourierModel", rec: "Recording") -> TwoLevel | None:
    """The two-level samples the estimator finds on calibration's own recording ``rec`` with its grating fused and
    the ``model`` just fitted; None without a grating, with too few frames placed, or where none is."""
    from graytrack.core.estimator import kernel
    from graytrack.core.estimator.filter import Estimator, _calibration_reference
    from graytrack.core.estimator.settings import EstimatorSettings
    from graytrack.core.recording import acceleration_phases

    reference = _calibration_reference(model, rec)
    if reference is None or np.isfinite(reference).sum() < MIN_FRAMES:
        return None
    estimator = Estimator(model, settings=EstimatorSettings().for_recording(rec.meta), grating="fuse",
                          stage_phases=acceleration_phases(rec.meta))
    usable = reference[np.isfinite(reference)]
    edges = np.quantile(usable, np.linspace(0.0, 1.0, STRETCHES + 1)[1:-1])
    rows, values, phases, times, places = [], [], [], [], []
    target = estimator.pixels[kernel.PX_TARGET]
    period = model.period_mm
    readings = reference.tolist()
    for k, when in enumerate(np.asarray(rec.t, dtype=np.float64).tolist()):
        estimate = estimator.update(rec.frames[k], when, readings[k])
        if not math.isfinite(estimate.x_mm):
            continue
        h, r, _ = estimator.left(rec.frames[k])
        rows.append(r.astype(np.float32))
        values.append(h.astype(np.float32))
        phases.append(((estimate.x_mm + estimate.place_mm + target) / period).astype(np.float32))
        times.append(when)
        places.append(estimate.x_mm)
    if len(rows) < MIN_FRAMES:
        return None
    return found(np.array(rows, dtype=np.float64), np.array(values, dtype=np.float64),
                 np.array(phases, dtype=np.float64), np.array(times), np.searchsorted(edges, np.array(places)))
