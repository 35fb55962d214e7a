"""Camera against grating while tracking: has the target's scale or offset moved since calibration?

Calibration makes the camera agree with the stage's grating; a print that grows (paper in
humidity), a camera that shifts on its mount or a stage re-homed elsewhere breaks that agreement
as a straight line in position: ``camera − grating = offset + scale·(x − x_c)``. The image cannot
see it (the model still fits every frame), the grating can. So whenever frames come with a grating
reading, a weighted line is fitted to ``camera − grating`` over a sliding window of frames:

- weights from each frame's bound (its Cramér–Rao bound, with the grating's quantisation added);
- uncertainty from both the bounds and the observed scatter (the covariance is scaled up by the
  window's χ² per degree of freedom when that exceeds 1), so a noisy grating or a vibration the
  camera and the grating see differently widens the uncertainty instead of faking evidence;
- the grating's rounding is fixed wherever the stage rests: it averages down with the number of
  places read, not of frames (a stage resting at two places does not make a scale of it); so is the
  error the model makes at a place it was not fitted to (``reference_place_sigma_um``: its
  coefficients' noise, about the calibration's bound × √(coefficients / frames)). A stage parked
  for a thousand frames measures that place's offset to a fraction of it, and without this term
  an error at the bound read as a drift (the `lab` rig at rest: `scale` at 8 of 15 positions
  whose errors were 0.2–0.5 of a bound);
- drift is measured from the calibration's own line: the calibration recording tracked by the
  model it produced (:func:`~graytrack.core.calibration_line.record_calibration_line`, kept in the model's info as
  ``reference_line``), with its uncertainty. A model need not agree with its grating exactly (a
  closed-loop model on a rig with 3 % PRNU was
  seen 220 ppm off its own calibration run); what changed since is the news.
  Its structure along the stroke (a model's error is no straight line) is kept too
  (``reference_structure_um``): a window seeing one stretch may find that much without any change.
  A model without that line is compared with zero, its uncertainty taken from its K frames spread
  over the stroke (std s): σ/√K for the offset, σ/(√K·s) for the scale (else one window's);
- a weak prior on the scale (``prior_scale_ppm``) keeps the fit defined while the stage stands
  still: then only the offset is observed, as it should be.

A drift is flagged (``stale``) when it is beyond its uncertainty (χ² of offset and scale together, 2 dof,
above ``z_on²``) and physically meaningful: the error it makes somewhere over the calibrated
stroke exceeds ``floor_um`` and half a grating step (an offset below half a step cannot be told
from the grating's own rounding while the stage stands still). The flag holds until the χ² falls
below ``z_off²`` (hysteresis: a window sliding over a threshold does not flicker).

The same estimate serves an online trim (:class:`Trimmer`): adopted only on evidence, logged,
reversible; once adopted, drift is measured against the trim instead of the calibration. Its
evidence is the flag's: a change since calibration beyond both uncertainties. A camera that
disagrees with the grating only within what its calibration knew (a sweep of 63 frames knows the
scale to ~60 ppm) is not trimmed: that is a calibration to repeat, not a drift to follow, and a
window of frames resting at a few places (each with its own model error and grating rounding)
would otherwise be taken for a line it is not.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

from typing import Callable

import numpy as np

from graytrack.core.adequacy import inadequacy
from graytrack.core.holdout import held_out
from graytrack.core.poly_follow import ChosenFollower
from graytrack.core.trim_follow import Following
from graytrack.core.watches import _kernels

DEFAULT_WINDOW = 500  # frames in the sliding window
# frames before the window says anything: its test (χ² beyond z_on², the covariance scaled up by the
# window's own scatter) holds its false alarms at a few frames too, and every frame waited for is a
# frame a grown print places unflagged (a 16-row strip 250 ppm off: 3.6 bounds each, the first 29
# frames made the trimmed run 1.41× its bound, the first 5 make it 1.19×)
MIN_FRAMES = 6
JUMP_FRAMES = 15  # outliers in a row that say the line itself jumped (a glint lasts a few frames: more than that)
Z_ON, Z_OFF = 5.0, 3.0  # drift significance (σ) to raise and to clear the flag
FLOOR_UM = 0.2  # the smallest error over the stroke worth a flag (below a grating ruler's certified accuracy)
PRIOR_SCALE_PPM = 1000.0  # standard deviation of the prior on the scale: unobservable while the stage rests
UNTRIMMED_BEHIND = 2.0  # bounds: untrimmed positions this far off the calibration's line, significantly, are flagged
GATE = 8.0  # a frame whose residual is beyond this many of its σ from the line is an outlier (not added)
REFINE = 0.7  # a refined trim is logged when its scale or offset σ fell this much since the last logged one
# ... and refined, quietly, when a later window knows its scale or offset this much better (σ ratio): a
# trim taken early extrapolates its scale over stretches it has not seen, so it follows every clear
# improvement (16 rows, 250 ppm grown: 1.10-1.27x its bound over a run, 1.07-1.19x this way)
REFINE_QUIET = 0.95
UPDATE_EVERY = 4  # frames between fits and tests (every frame while flagged): a quarter of the cost, a few frames' lag
RECOMPUTE_EVERY = 4096  # frames between exact re-sums of the window (bounds rounding drift)


@dataclass(frozen=True)
class Line:
    """``camera − grating = offset + scale·(x − center)``, with its covariance.

    Units: offset in µm, scale in ppm (µm per m, i.e. 1e-6), covariance ``(var_o, cov_os, var_s)``
    in µm², µm·ppm and ppm².
    """

    offset_um: float = 0.0
    scale_ppm: float = 0.0
    covariance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    center_mm: float = 0.0
    frames: int = 0
    mean_mm: float = float("nan")  # the weighted mean position of the frames it was fitted to

    @property
    def offset_sigma_um(self) -> float:
        return math.sqrt(self.covariance[0])

    @property
    def scale_sigma_ppm(self) -> float:
        return math.sqrt(self.covariance[2])

    def at_um(self, x_mm: float | np.ndarray) -> float | np.ndarray:
        """The line's value at position(s) ``x_mm`` (µm)."""
        return self.offset_um + self.scale_ppm * 1e-3 * (np.asarray(x_mm) - self.center_mm)

    def sigma_um(self, x_mm: float | np.ndarray) -> float | np.ndarray:
        """Its standard error at ``x_mm`` (µm)."""
        d = (np.asarray(x_mm) - self.center_mm) * 1e-3  # ppm·mm → µm
        var_o, cov, var_s = self.covariance
        return np.sqrt(np.maximum(var_o + 2 * d * cov + d * d * var_s, 0.0))

    def describe(self) -> str:
        """One line: the line's value where its frames were (the best-known point) and its scale."""
        at = self.mean_mm if math.isfinite(self.mean_mm) else self.center_mm
        return (f"camera - grating {float(self.at_um(at)):+.3f} +/- {float(self.sigma_um(at)):.3f} um around "
                f"{at:.3f} mm, scale {self.scale_ppm:+.1f} +/- {self.scale_sigma_ppm:.1f} ppm, offset "
                f"{self.offset_um:+.3f} +/- {self.offset_sigma_um:.3f} um at {self.center_mm:.3f} mm "
                f"({self.frames} frames)")

    @classmethod
    def from_dict(cls, doc: dict) -> "Line":
        """The inverse of :meth:`as_dict` (as kept in a model's info)."""
        var_o, var_s = float(doc["offset_sigma_um"]) ** 2, float(doc["scale_sigma_ppm"]) ** 2
        return cls(float(doc["offset_um"]), float(doc["scale_ppm"]), (var_o, float(doc.get("covariance", 0.0)), var_s),
                   float(doc["center_mm"]), int(doc.get("frames", 0)), float(doc.get("mean_mm") or math.nan))

    def as_dict(self) -> dict[str, float | int | None]:
        """Its figures, and its value where its frames were (``at_mean_um``: what a resting stage shows)."""
        known = math.isfinite(self.mean_mm)
        return {"offset_um": self.offset_um, "offset_sigma_um": self.offset_sigma_um, "scale_ppm": self.scale_ppm,
                "scale_sigma_ppm": self.scale_sigma_ppm, "covariance": self.covariance[1],
                "center_mm": self.center_mm, "frames": self.frames,
                "mean_mm": self.mean_mm if known else None,
                "at_mean_um": float(self.at_um(self.mean_mm)) if known else None,
                "at_mean_sigma_um": float(self.sigma_um(self.mean_mm)) if known else None}


@dataclass(frozen=True)
class StructureProfile:
    """The model's own error along the stroke, camera − grating about the calibration's line, stretch
    by stretch (the calibration's frames binned by grating reading): fixed in position, so a run
    read through the same model shows it again at the same places, and it is taken out of camera −
    grating before the line is fitted. Without it the monitor could only allow for it: a window over
    the whole stroke would carry a scale uncertainty of that structure over the half-stroke (0.84 µm
    of structure: 160 ppm), and a print grown 400 ppm read by a seed model on a rig with fixed
    pattern noise would go unflagged, 1.46× its bound against the truth, 6 frames 4+ bounds off."""

    centers_mm: tuple[float, ...]  # bin centres, increasing (bins with too few frames left out)
    values_um: tuple[float, ...]  # mean camera − grating − line there
    noise_um: float  # rms standard error of those means: what correcting by them adds, fixed per place
    residual_um: float  # what is left beyond noise after the correction, stretch by stretch

    def at_um(self, reference_mm):
        """The structure at grating reading(s) ``reference_mm`` (µm): linear between bin centres, the
        end values beyond them."""
        return np.interp(reference_mm, self.centers_mm, self.values_um)

    def at_one_um(self, reference_mm: float) -> float:
        """:meth:`at_um` of one reading in plain floats (a tracked frame's: np.interp costs 2 µs a call)."""
        centers, values = self.centers_mm, self.values_um
        k = bisect.bisect_right(centers, reference_mm)
        if k == 0:
            return values[0]
        if k == len(centers):
            return values[-1]
        slope = (values[k] - values[k - 1]) / (centers[k] - centers[k - 1])  # as np.interp rounds it
        return slope * (reference_mm - centers[k - 1]) + values[k - 1]

    def as_dict(self) -> dict:
        return {"centers_mm": [round(v, 6) for v in self.centers_mm],
                "values_um": [round(v, 4) for v in self.values_um],
                "noise_um": round(self.noise_um, 4), "residual_um": round(self.residual_um, 4)}

    @classmethod
    def from_dict(cls, doc: dict) -> "StructureProfile":
        return cls(tuple(float(v) for v in doc["centers_mm"]), tuple(float(v) for v in doc["values_um"]),
                   float(doc["noise_um"]), float(doc["residual_um"]))


@dataclass
class ReferenceMonitor:
    """The sliding-window line of camera − grating and the drift test against the current reference
    line (zero, the calibration's, until a trim is adopted). Pure numerics; O(1) per frame."""

    center_mm: float
    half_stroke_mm: float
    window: int = DEFAULT_WINDOW
    reference_sigma_mm: float = 0.0  # the grating's own noise per reading (quantisation: step/√12)
    resolution_mm: float = 0.0  # the grating's step (the offset floor is half of it)
    floor_um: float = FLOOR_UM
    z_on: float = Z_ON
    z_off: float = Z_OFF
    min_frames: int = MIN_FRAMES
    prior_scale_ppm: float = PRIOR_SCALE_PPM
    calibration_frames: int = 0  # frames the calibration had (0: unknown, taken as one window's)
    calibration_x_std_mm: float = 0.0  # the spread of their positions
    calibration: Line | None = None  # the calibration run's own line (None: zero, see above)
    calibration_structure_um: float = 0.0  # rms of the calibration run's camera − grating about that line, in stretches
    place_sigma_um: float = 0.0  # the model's error at a place it was not fitted to: fixed there, like the rounding
    structure: StructureProfile | None = None  # the model's error along the stroke, taken out of camera − grating
    baseline: Line | None = None  # the trim in force, which drift is then measured against
    stale: bool = False
    significance: float = 0.0  # χ² (2 dof) of the latest drift against its uncertainty and the reference line's
    estimate: Line | None = None  # the window's line, once it has min_frames
    # Per frame in plain floats (numpy's per-call cost would dominate a six-number update at 1 kHz)
    _rows: list[tuple[float, float, float, float]] = field(init=False, repr=False)  # ring: (w, d, r, new place)
    _sums: list[float] = field(init=False, repr=False)  # Σw, Σwd, Σwd², Σwr, Σwrd, Σwr², frames at a new place
    _count: int = field(default=0, init=False)
    _next: int = field(default=0, init=False)
    _since_recompute: int = field(default=0, init=False)
    _outliers: int = field(default=0, init=False)
    _fed: int = field(default=0, init=False)  # frames added since the start
    _scatter: float = field(default=1.0, init=False)  # the last fit's χ² per dof (at least 1)
    _last_reference: float = field(default=math.nan, init=False)

    def __post_init__(self) -> None:
        if self.window < max(self.min_frames, 3):
            raise ValueError(f"window must hold at least {max(self.min_frames, 3)} frames, got {self.window}")
        self._rows = [(0.0, 0.0, 0.0, 0.0)] * self.window
        self._sums = [0.0] * 7

    @classmethod
    def for_model(cls, model, reference_resolution_mm: float = 0.0, **options) -> "ReferenceMonitor":
        """A monitor about the centre of ``model``'s calibrated stroke (``stroke_range_mm``), its
        floor judged over that stroke; ``reference_resolution_mm``: the grating's step, if known."""
        lo, hi = model.stroke_range_mm
        step = max(float(reference_resolution_mm), 0.0)
        info = getattr(model, "info", {}) or {}
        options.setdefault("calibration_frames", int(info.get("calibration_frames", 0)))
        options.setdefault("calibration_x_std_mm", float(info.get("calibration_x_std_mm", 0.0)))
        if isinstance(info.get("reference_line"), dict):
            options.setdefault("calibration", Line.from_dict(info["reference_line"]))
            options.setdefault("calibration_structure_um", float(info.get("reference_structure_um") or 0.0))
        options.setdefault("place_sigma_um", float(info.get("reference_place_sigma_um") or 0.0))
        if isinstance(info.get("reference_structure_profile"), dict) and "calibration" in options:
            # the structure corrected for: what is left of it, and the correction's own noise (fixed per place)
            profile = StructureProfile.from_dict(info["reference_structure_profile"])
            options.setdefault("structure", profile)
            options["calibration_structure_um"] = profile.residual_um
            options["place_sigma_um"] = math.hypot(options["place_sigma_um"], profile.noise_um)
        return cls(0.5 * (lo + hi), 0.5 * (hi - lo), reference_sigma_mm=step / math.sqrt(12.0), resolution_mm=step,
                   **options)

    @property
    def frames(self) -> int:
        return self._count

    def reset(self) -> None:
        """Forget the window (a new model: the line starts again from its calibration)."""
        self._rows = [(0.0, 0.0, 0.0, 0.0)] * self.window
        self._sums = [0.0] * 7
        self._last_reference, self._scatter = math.nan, 1.0
        self._count = self._next = self._since_recompute = self._outliers = 0
        self.estimate, self.stale, self.significance, self.baseline = None, False, 0.0, None

    def observe(self, x_mm: float, reference_mm: float, bound_mm: float) -> bool:
        """Add one frame (the camera's untrimmed position, the grating at the same instant, the
        frame's bound); returns whether the drift is flagged. Frames missing any of the three are skipped."""
        if not (math.isfinite(x_mm) and math.isfinite(reference_mm) and math.isfinite(bound_mm) and bound_mm > 0):
            return self.stale
        if self.structure is not None:  # the model's own error here is no drift (as observe_many takes it out)
            x_mm = x_mm - self.structure.at_one_um(reference_mm) * 1e-3
        d = reference_mm - self.center_mm
        r = (x_mm - reference_mm) * 1e3
        var = (bound_mm * bound_mm + self.reference_sigma_mm * self.reference_sigma_mm) * 1e6
        if self._is_outlier(d, r, var):
            return self.stale
        new_place = not abs(reference_mm - self._last_reference) < max(self.resolution_mm, 1e-12)
        self._last_reference = reference_mm
        self._add(1.0 / var, d, r, float(new_place))
        if self._since_recompute >= RECOMPUTE_EVERY:
            self._recompute()
        return self._added()

    def _added(self) -> bool:
        """A frame was added to the window: the line is fitted and tested again every few frames."""
        self._fed += 1
        if self._fed % UPDATE_EVERY == 0 or self._count == self.min_frames or self.stale:
            self._update()
        return self.stale

    def observe_many(self, x_mm: np.ndarray, reference_mm: np.ndarray, bound_mm: np.ndarray, feed: np.ndarray,
                     on_rise: Callable[[int], None] | None = None, scatter: np.ndarray | None = None,
                     lines: np.ndarray | None = None) -> np.ndarray:
        """:meth:`observe` of each frame where ``feed`` is set, in order: the flag after every frame
        (fed or not); into ``scatter`` (when given) :attr:`scatter` as it stood before each frame, what
        a frame's gate read between them (core/watches/scale.py's running mean); into ``lines`` (when
        given, ``(n, 3)``) the :attr:`estimate` after each frame: 1 if there is one, its scale (ppm) and
        the scale's variance (what the scale watch names a stretch against, frame by frame). ``on_rise(k)`` is
        called when the flag rises at frame k, the monitor then as it stood after that frame.
        Compiled (core/watches/_kernels.py): the same numbers as :meth:`observe` frame by frame,
        which it is without numba."""
        n = len(x_mm)
        stale = np.zeros(n, dtype=bool)
        scatter = np.empty(n) if scatter is None else scatter
        recorded = lines if lines is not None else np.empty((0, 3))
        if not _kernels.COMPILED:
            for k in range(n):
                before = self.stale
                scatter[k] = self._scatter
                if feed[k]:
                    self.observe(float(x_mm[k]), float(reference_mm[k]), float(bound_mm[k]))
                stale[k] = self.stale
                self._record_line(recorded, k)
                if on_rise is not None and self.stale and not before:
                    on_rise(k)
            return stale
        x, ref, bound = (np.ascontiguousarray(v, dtype=np.float64) for v in (x_mm, reference_mm, bound_mm))
        if self.structure is not None:  # taken out of the position the loop reads: r = (x − ref)·1e3 − structure
            x = x - self.structure.at_um(ref) * 1e-3
        feed = np.ascontiguousarray(feed, dtype=np.bool_)
        ip, p, ist, fst, est, rows = self._packed()
        start = 0
        while start < n:
            start, stop = _kernels._reference_run(ip, p, ist, fst, est, rows, x, ref, bound, feed, stale, scatter,
                                                  start, on_rise is not None, recorded)
            if stop == _kernels.DONE:
                break
            self._unpack(ist, fst, est, rows)
            if stop == _kernels.RECOMPUTE:  # frame `start` was added; numpy re-sums the window, then it is finished
                before = self.stale
                self._recompute()
                stale[start] = self._added()
                self._record_line(recorded, start)
                if on_rise is not None and self.stale and not before:
                    on_rise(start)
                start += 1
            elif on_rise is not None:  # (the kernel stops at a rise only when asked to)
                on_rise(start - 1)
            ip, p, ist, fst, est, rows = self._packed()
        self._unpack(ist, fst, est, rows)
        return stale

    def _record_line(self, lines: np.ndarray, k: int) -> None:
        """Row ``k`` of :meth:`observe_many`'s ``lines`` (none when it has no rows): the estimate now."""
        if len(lines):
            line = self.estimate
            lines[k] = (1.0, line.scale_ppm, line.covariance[2]) if line is not None else (0.0, 0.0, 0.0)

    def _packed(self) -> tuple[np.ndarray, ...]:
        """The state as the compiled loop takes it (core/watches/_kernels.py names each slot)."""
        def line(value: Line | None) -> list[float]:
            return [1.0, value.offset_um, value.scale_ppm, *value.covariance] if value is not None else [0.0] * 6
        ip = np.array([self.window, self.min_frames, JUMP_FRAMES, self.calibration_frames,
                       RECOMPUTE_EVERY, UPDATE_EVERY], dtype=np.int64)
        p = np.array([self.center_mm, self.half_stroke_mm, self.reference_sigma_mm, max(self.resolution_mm, 1e-12),
                      max(self.floor_um, 0.5 * self.resolution_mm * 1e3), self.z_on ** 2, self.z_off ** 2,
                      self._prior_weight(), 1.0 / self._prior_weight(), self._place_variance_um2(),
                      self.calibration_structure_um ** 2, self.calibration_x_std_mm,
                      *line(self.baseline), *line(self.calibration)], dtype=np.float64)
        estimate = self.estimate
        ist = np.array([self._count, self._next, self._since_recompute, self._outliers, self._fed, self.stale,
                        estimate is not None], dtype=np.int64)
        fst = np.array([*self._sums, self._scatter, self._last_reference, self.significance])
        est = np.array([estimate.offset_um, estimate.scale_ppm, *estimate.covariance, estimate.center_mm,
                        estimate.frames, estimate.mean_mm] if estimate is not None else [0.0] * 8)
        return ip, p, ist, fst, est, np.array(self._rows, dtype=np.float64)

    def _unpack(self, ist: np.ndarray, fst: np.ndarray, est: np.ndarray, rows: np.ndarray) -> None:
        self._count, self._next, self._since_recompute, self._outliers, self._fed = (int(v) for v in ist[:5])
        self.stale = bool(ist[5])
        values = fst.tolist()
        self._sums, (self._scatter, self._last_reference, self.significance) = values[:7], values[7:]
        if ist[6]:
            e = est.tolist()
            self.estimate = Line(e[0], e[1], (e[2], e[3], e[4]), e[5], int(e[6]), e[7])
        else:
            self.estimate = None
        self._rows = list(map(tuple, rows.tolist()))

    def snapshot(self) -> tuple:
        """The monitor's running state (as the compiled loop packs it, and the trim in force), to go
        back to with :meth:`restore`."""
        _, _, *state = self._packed()
        return (*state, self.baseline)

    def restore(self, state: tuple) -> None:
        *packed, self.baseline = state
        self._unpack(*packed)

    @property
    def scatter(self) -> float:
        """The window's χ² per degree of freedom about its line (at least 1): how much wider than their
        bounds camera − grating scatters (a vibration the two see differently, a noisy grating)."""
        return self._scatter

    def _is_outlier(self, d: float, r: float, var: float) -> bool:
        """A frame far off the window's line (a glint, a lost period): left out, unless a run of them
        says the line itself jumped (a camera knocked, a stage re-homed): then the window restarts."""
        line = self.estimate
        if line is None:
            return False
        scatter = self._scatter
        dd = d * 1e-3  # ppm·mm → µm
        var_o, cov, var_s = line.covariance
        spread = var * scatter + var_o + 2 * dd * cov + dd * dd * var_s
        error = r - line.offset_um - line.scale_ppm * dd
        if error * error <= GATE * GATE * spread:
            self._outliers = 0
            return False
        self._outliers += 1
        if self._outliers < JUMP_FRAMES:
            return True
        baseline, stale = self.baseline, self.stale
        self.reset()  # a jump: the old window no longer describes the line
        self.baseline, self.stale = baseline, stale
        return False

    def _add(self, w: float, d: float, r: float, new_place: float) -> None:
        slot = self._next
        if self._count == self.window:  # the oldest frame leaves as this one comes in
            _kernels.slide_window_python(self._sums, w, d, r, new_place, *self._rows[slot])
        else:
            self._count += 1
            _kernels.slide_window_python(self._sums, w, d, r, new_place, 0.0, 0.0, 0.0, 0.0)
        self._rows[slot] = (w, d, r, new_place)
        self._next = (slot + 1) % self.window
        self._since_recompute += 1

    def _recompute(self) -> None:
        """The window's sums afresh (every RECOMPUTE_EVERY frames added: bounds their rounding drift)."""
        rows = np.array(self._rows[: self._count] if self._count < self.window else self._rows)
        self._sums = ([float(v) for v in _terms(rows[:, 0], rows[:, 1], rows[:, 2], total=True)]
                      + [float(rows[:, 3].sum())])
        self._since_recompute = 0

    def _update(self) -> None:
        if self._count < self.min_frames:
            return
        line = self._fit()
        self.estimate = line
        base = self.baseline or self.calibration
        do = line.offset_um - (base.offset_um if base else 0.0)
        ds = line.scale_ppm - (base.scale_ppm if base else 0.0)
        meaningful = (abs(do) + abs(ds) * 1e-3 * self.half_stroke_mm
                      >= max(self.floor_um, 0.5 * self.resolution_mm * 1e3))
        reference = base.covariance if base is not None else self._calibration_covariance(line)
        self.significance = _chi2(do, ds, line.covariance, _plus(reference, self._structure_covariance()))
        self.stale = meaningful and self.significance >= (self.z_off if self.stale else self.z_on) ** 2

    def _fit(self) -> Line:
        """The weighted line with the scale's prior, its covariance scaled by the observed scatter."""
        sw, swd, swdd, swr, swrd, _, _ = self._sums
        prior = self._prior_weight()
        base_scale = (self.baseline.scale_ppm if self.baseline else 0.0) * 1e-3  # µm/mm
        # normal equations in (offset µm, scale µm/mm)
        n11, n12, n22 = sw, swd, swdd + prior
        r1, r2 = swr, swrd + prior * base_scale
        det = n11 * n22 - n12 * n12
        offset = (n22 * r1 - n12 * r2) / det
        slope = (n11 * r2 - n12 * r1) / det
        self._scatter = max(self._chi2_per_dof(offset, slope), 1.0)
        inflate = self._scatter / det
        var_o, cov, var_s = self._rounding_covariance()
        return Line(offset, slope * 1e3, (n22 * inflate + var_o, (-n12 * inflate + cov) * 1e3,
                                          (n11 * inflate + var_s) * 1e6), self.center_mm, self._count,
                    self.center_mm + swd / sw)

    def _rounding_covariance(self) -> tuple[float, float, float]:
        """The grating's rounding and the model's error at a place, fixed wherever the stage rests:
        independent only between the places the window was read at, so they average down with
        their number, not the frames'.
        In (µm², µm²/mm, µm²/mm²) about the centre."""
        sigma2 = self._place_variance_um2()
        if sigma2 == 0.0:
            return 0.0, 0.0, 0.0
        sw, swd, swdd = self._sums[0], self._sums[1], self._sums[2]
        places = max(self._sums[6], 1.0)
        mean = swd / sw
        spread2 = max(swdd / sw - mean * mean, 0.0)
        var_s = sigma2 / (places * spread2) if spread2 > 0 else math.inf
        var_s = min(var_s, 1.0 / self._prior_weight())
        return sigma2 / places + mean * mean * var_s, -mean * var_s, var_s

    def _place_variance_um2(self) -> float:
        """What a place read adds, the same for every frame there: the grating's rounding and the
        model's own error at that place (µm²)."""
        return (self.reference_sigma_mm * 1e3) ** 2 + self.place_sigma_um ** 2

    def _structure_covariance(self) -> tuple[float, float, float]:
        """The model's own structure along the stroke (``calibration_structure_um``): a window over a
        stretch of half-span h may see the line off by that much where its frames are, and its slope
        by that over h; about the centre, that slope's error reaches the offset over the lever from
        the window's frames (as the rounding's does). Held at the centre, a window of 68 frames over
        the stroke's first 1.3 mm had its slope (a seed model's telegraph-pixel residue, +2400 ppm)
        extrapolated 4.6 mm as an offset known to 0.2 µm: 5.4 sigma, and a steady run trimmed."""
        sigma2 = self.calibration_structure_um ** 2
        if sigma2 == 0.0:
            return 0.0, 0.0, 0.0
        sw, swd, swdd = self._sums[0], self._sums[1], self._sums[2]
        mean = swd / sw
        half2 = 3.0 * max(swdd / sw - mean * mean, 0.0)  # (half-span)² of an even spread with that variance
        var_s = min(sigma2 / half2 if half2 > 0 else math.inf, 1.0 / self._prior_weight())  # (µm/mm)²
        return sigma2 + mean * mean * var_s, -mean * var_s * 1e3, var_s * 1e6

    def _calibration_covariance(self, line: Line) -> tuple[float, float, float]:
        """The calibration's line, known from its frames with the bound the window's frames have."""
        k, spread = self.calibration_frames, self.calibration_x_std_mm
        if k < 3 or not spread > 0:
            return line.covariance
        sw = self._sums[0]
        var = self._count / sw * max(self._chi2_per_dof(line.offset_um, line.scale_ppm * 1e-3), 1.0)  # µm², per frame
        return var / k, 0.0, var / (k * spread * spread) * 1e6

    def _prior_weight(self) -> float:
        return 1.0 / (self.prior_scale_ppm * 1e-3) ** 2  # in (µm/mm)⁻²

    def _chi2_per_dof(self, a: float, b: float) -> float:
        """The window's weighted χ² per degree of freedom about the line ``a + b·d`` (µm, µm/mm)."""
        sw, swd, swdd, swr, swrd, swrr, _ = self._sums
        chi2 = swrr - 2 * a * swr - 2 * b * swrd + a * a * sw + 2 * a * b * swd + b * b * swdd
        return max(chi2, 0.0) / max(self._count - 2, 1)


def _plus(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    return a[0] + b[0], a[1] + b[1], a[2] + b[2]


def _chi2(do: float, ds: float, cov: tuple[float, float, float], other: tuple[float, float, float]) -> float:
    """χ² of the difference (offset µm, scale ppm) under the sum of two covariances."""
    a, b, c = cov[0] + other[0], cov[1] + other[1], cov[2] + other[2]
    det = a * c - b * b
    return (c * do * do - 2 * b * do * ds + a * ds * ds) / det if det > 0 else 0.0


def _terms(w, d, r, total: bool = False):
    """w, wd, wd², wr, wrd, wr² of one frame (floats), or their sums over many (arrays, ``total``)."""
    terms = (w, w * d, w * d * d, w * r, w * r * d, w * r * r)
    return tuple(t.sum() for t in terms) if total else terms


def drift_message(monitor: ReferenceMonitor) -> str:
    """The sentence for a raised flag: how far, how sure, against what."""
    against = "the trim in force" if monitor.baseline is not None else "calibration"
    line = monitor.estimate
    return f"camera against grating drifted from {against} ({monitor.significance ** 0.5:.1f} sigma): " + (
        line.describe() if line is not None else "")


@dataclass(frozen=True)
class TrimEvent:
    """A change of the trim: ``kind`` is ``trim_applied`` or ``trim_cleared``."""

    kind: str
    message: str
    line: Line | None


@dataclass
class Trimmer:
    """An online scale/offset trim on the monitor's evidence: ``x' = x − (offset + scale·(x − x_c))``.

    Adopted only when the monitor flags a drift (never without evidence), refined when a later
    window knows the line clearly better (its scale or offset σ below :data:`REFINE` of the
    trim's: a first trim taken on a short stretch of the stroke is improved as the stage moves
    on, in a few logged steps rather than every frame), and cleared on
    request (a new calibration clears it too). The window's line lags a drift in time by half the
    window: a :class:`~graytrack.core.trim_follow.Follower` of what is left after the trim follows it
    frame by frame (a correction on top of the line once it is significant, with its σ, and the lag
    the frame still carries: drift rate × age of the evidence). ``step`` applies the trim in force
    to a position and gives what it adds to the frame's bound (its σ and lag, in quadrature).
    """

    monitor: ReferenceMonitor
    trim: Line | None = None
    logged: Line | None = None  # the trim as last logged (quiet refinements since are not events)
    # the line, or a quadratic where the drift curves (a cycle): core/poly_follow.py
    follower: ChosenFollower = field(default_factory=ChosenFollower)
    following: Following = field(default_factory=Following)  # the follower's word on the last frame fed
    drifted: bool = False  # the monitor's flag as the last frame left it, before a trim took the drift up
    _x_mm: float = field(default=math.nan, init=False)  # the last frame's position (where a new line is restated)

    def observe(self, x_mm: float, reference_mm: float, bound_mm: float) -> TrimEvent | None:
        """Feed one frame to the monitor and adopt or refine the trim; the event when it changed."""
        return self.feed(x_mm, reference_mm, bound_mm, True)

    def feed(self, x_mm: float, reference_mm: float, bound_mm: float, usable: bool) -> TrimEvent | None:
        """One frame (fed to the monitor and the follower when ``usable``), then :meth:`consider`."""
        self.follower.tick()
        known = usable and math.isfinite(x_mm) and math.isfinite(reference_mm) and bound_mm > 0
        if known:
            self._x_mm = x_mm
        if usable:
            self.monitor.observe(x_mm, reference_mm, bound_mm)
        self.drifted = self.monitor.stale
        event = self.consider()
        trim, monitor = self.trim, self.monitor
        # before a trim, the follower watches the positions against the calibration's line: a drift that
        # starts with the run is told (:meth:`behind`) before the window's line has the evidence to trim
        line = trim if trim is not None else monitor.calibration
        if known:
            residual = (x_mm - reference_mm) * 1e3 - (float(line.at_um(x_mm)) if line is not None else 0.0)
            if monitor.structure is not None:  # the model's own error here, as the monitor takes it out
                residual -= monitor.structure.at_one_um(reference_mm)
            self.follower.add(residual, (bound_mm ** 2 + monitor.reference_sigma_mm ** 2) * 1e6)
        self.following = self.follower.now()
        return event

    def consider(self) -> TrimEvent | None:
        """Adopt the monitor's line when it is evidence (or a clearly better estimate of the trim)."""
        line, monitor = self.monitor.estimate, self.monitor
        if line is None:
            return None
        if monitor.stale:
            against = "the trim in force" if self.trim is not None else "calibration"
            return self._adopt(line, f"drifted from {against} by {monitor.significance ** 0.5:.1f} sigma")
        trim = self.trim
        if trim is None or line.frames < monitor.min_frames or not _better(line, trim, REFINE_QUIET):
            return None
        logged = self.logged
        event = self._adopt(line, "refined: a window that knows the line better")
        if logged is not None and not _better(line, logged, REFINE):
            self.logged = logged
            return None  # in force and shown in the status, not worth a line of the event log
        return event

    def _adopt(self, line: Line, why: str) -> TrimEvent:
        old, x = self.trim if self.trim is not None else self.monitor.calibration, self._x_mm
        if not math.isfinite(x):
            self.follower.reset()
        else:  # what the follower kept is restated against the new line
            self.follower.shift(float(line.at_um(x)) - (float(old.at_um(x)) if old is not None else 0.0))
        self.trim = self.logged = line
        self.monitor.baseline = line
        self.monitor.stale = False
        self.monitor.significance = 0.0
        return TrimEvent("trim_applied", f"trim applied ({why}): {line.describe()}", line)

    def clear(self, why: str = "on request") -> TrimEvent | None:
        """Drop the trim and measure drift against the calibration again, on a fresh window (else the
        evidence of the frames before would re-adopt it at once)."""
        if self.trim is None:
            return None
        self.trim = self.logged = None
        self.follower.reset()
        self.following = Following()
        self.monitor.reset()  # fresh evidence for any new trim, not the frames the old one came from
        return TrimEvent("trim_cleared", f"trim cleared ({why})", None)

    def step(self, x_mm: float) -> tuple[float, float]:
        """(the trimmed position in mm, what the trim adds to its bound there in mm: the line's
        standard error (while no correction is in force), the follower's correction's and the lag, in
        quadrature); no trim: (x, 0)."""
        trim = self.trim
        if trim is None or not math.isfinite(x_mm):
            return x_mm, 0.0
        f = self.following
        x = x_mm - (float(trim.at_um(x_mm)) + f.correction_um) * 1e-3
        # a correction in force measured what the line leaves here, the line's own error with it: its σ
        # stands for both (a cycle's line, far from a line, would widen 16-row bounds 2.5-fold, to 1 µm)
        line_um = 0.0 if f.correction_um else float(trim.sigma_um(x_mm))
        return x, math.sqrt(line_um ** 2 + f.sigma_um ** 2 + f.lag_um ** 2) * 1e-3

    def behind(self, bound_mm: float) -> bool:
        """The trim in force lags this frame by more than its bound (flagged: never silently behind);
        before a trim, the positions are off the calibration's line by more than :data:`UNTRIMMED_BEHIND`
        of their bound, significantly (a lens's slide from the run's first frame, 0.5 bound a frame:
        frames 6-10 of a 16-row run 4-6.5 bounds off, before the window's line could trim)."""
        if self.trim is None:
            return abs(self.following.correction_um) > UNTRIMMED_BEHIND * bound_mm * 1e3
        return self.following.behind(bound_mm)


def _better(line: Line, than: Line, ratio: float) -> bool:
    """Whether ``line`` knows its scale or its offset better than ``than`` by the σ ``ratio``."""
    return line.scale_sigma_ppm < ratio * than.scale_sigma_ppm or line.offset_sigma_um < ratio * than.offset_sigma_um


@dataclass
class Followed:
    """A recording followed frame by frame (what the daemon would have done live)."""

    stale: np.ndarray  # the drift was flagged at this frame
    x_mm: np.ndarray  # positions, trimmed when a trim was in force
    trim_um: np.ndarray  # the correction applied (x − x'), µm; 0 without a trim
    trim_sigma_um: np.ndarray  # its standard error, µm
    events: list[tuple[int, TrimEvent | str]]  # (frame, a trim event or a flag message)
    final: Line | None  # the window's last line


def follow(monitor: ReferenceMonitor, x_mm: np.ndarray, reference_mm: np.ndarray, bound_mm: np.ndarray,
           usable: np.ndarray | None = None, trim: bool = False) -> Followed:
    """Run the monitor (and with ``trim`` the trimmer) causally over a tracked recording.

    ``usable`` (default: all) marks the frames whose position can be trusted (locked); the others
    are not fed, and are trimmed with the trim in force. Frame k's flag and trim use frames ≤ k only.
    """
    n = len(x_mm)
    usable = np.ones(n, dtype=bool) if usable is None else np.asarray(usable, dtype=bool)
    if not trim and not monitor.stale:  # the flag alone: the frames at once (observe_many), a message where it rises
        events: list[tuple[int, TrimEvent | str]] = []
        flags = monitor.observe_many(x_mm, reference_mm, bound_mm, usable,
                                     on_rise=lambda k: events.append((k, drift_message(monitor))))
        return Followed(flags, np.array(x_mm, dtype=np.float64), np.zeros(n), np.zeros(n), events, monitor.estimate)
    trimmer = Trimmer(monitor)
    stale = np.zeros(n, dtype=bool)
    out, corr, sigma = np.array(x_mm, dtype=np.float64), np.zeros(n), np.zeros(n)
    events = []
    was = False
    for k in range(n):
        x, ref, bound = float(x_mm[k]), float(reference_mm[k]), float(bound_mm[k])
        if not trim:
            if usable[k]:
                monitor.observe(x, ref, bound)
            flagged = monitor.stale
        else:  # the flag as the frame left the monitor, before the trim took it up
            event = trimmer.feed(x, ref, bound, bool(usable[k]))
            flagged = trimmer.drifted or trimmer.behind(bound)
        if flagged and not was:
            events.append((k, drift_message(monitor)))
        was = flagged
        stale[k] = flagged
        if trim:
            if event is not None:
                events.append((k, event))
                was = monitor.stale
            out[k], s = trimmer.step(x)
            corr[k], sigma[k] = (x - out[k]) * 1e3, s * 1e3
    return Followed(stale, out, corr, sigma, events, monitor.estimate)


def scale_tells(model) -> bool:
    """Whether camera − grating can say anything about the scale for this model: not for a model
    that errs beyond its bound on its own calibration frames (core/adequacy.py): its positions are
    off by its own structure, which a window's line would take for a drift, and they are flagged
    for ``geometry`` already."""
    return inadequacy(getattr(model, "info", None) or {}) is None


def structure_um(x_mm: np.ndarray, residual_um: np.ndarray, bound_um: np.ndarray, bins: int = 16) -> float:
    """The rms of camera − grating about its line, in stretches of the stroke, beyond the frames'
    noise: what a window seeing only one stretch may find off the line without anything having
    changed (a model's own error along the stroke is not a straight line)."""
    if x_mm.size < 2 * bins:
        return 0.0
    edges = np.linspace(x_mm.min(), x_mm.max() + 1e-12, bins + 1)
    which = np.clip(np.searchsorted(edges, x_mm, side="right") - 1, 0, bins - 1)
    excess = []
    for b in range(bins):
        r, noise = residual_um[which == b], bound_um[which == b]
        if r.size >= 3:
            excess.append(r.mean() ** 2 - np.mean(noise ** 2) / r.size)
    return float(math.sqrt(max(np.mean(excess), 0.0))) if excess else 0.0


def structure_profile(x_mm: np.ndarray, residual_um: np.ndarray, bound_um: np.ndarray,
                      bins: int = 16) -> StructureProfile | None:
    """camera − grating about its line (``residual_um`` at grating readings ``x_mm``) averaged stretch
    by stretch (``bins`` equal stretches, those with at least 3 frames): the model's own error along
    the stroke, with the noise of that average and what is left of the structure beyond it (in
    stretches, as :func:`structure_um` measures). None for too few frames, or when the means are
    mostly their own noise (the monitor then allows for the structure, as without a profile)."""
    if x_mm.size < 2 * bins:
        return None
    edges = np.linspace(x_mm.min(), x_mm.max() + 1e-12, bins + 1)
    which = np.clip(np.searchsorted(edges, x_mm, side="right") - 1, 0, bins - 1)
    counts = np.bincount(which, minlength=bins)
    kept = np.flatnonzero(counts >= 3)
    if kept.size < 2:
        return None
    centers = np.bincount(which, x_mm, bins)[kept] / counts[kept]
    means = np.bincount(which, residual_um, bins)[kept] / counts[kept]
    squares = np.bincount(which, residual_um * residual_um, bins)[kept] / counts[kept]
    n = counts[kept]
    standard_error2 = np.maximum(squares - means * means, 0.0) * n / (n - 1) / n
    noise_um = float(np.sqrt(standard_error2.mean()))
    # Only a structure well above the noise of its means is worth taking out: a model at its bound
    # along the stroke has bin means that are noise (16 rows: ±0.06 µm), and subtracting them would
    # only add it. Shrunk towards zero as the noise bids (positive-part James–Stein), kept from 1/2 up.
    shrink = 1.0 - noise_um ** 2 / max(float(np.mean(means * means)), 1e-300)
    if shrink < 0.5:
        return None
    means, noise_um = means * shrink, noise_um * shrink
    # What is left is measured out of sample: the held-out frames (core/holdout.py: whole readings, so no
    # held-out frame sits at a stop the profile saw) corrected by the profile of the rest (that profile's
    # own noise taken off again); in sample it would be nil by construction.
    held = held_out(x_mm)
    fit = ~held
    half = structure_profile(x_mm[fit], residual_um[fit], bound_um[fit], bins) \
        if x_mm.size >= 8 * bins and held.any() else None
    left = 0.0
    if half is not None:
        out_um = structure_um(x_mm[held], residual_um[held] - half.at_um(x_mm[held]), bound_um[held], bins)
        left = math.sqrt(max(out_um ** 2 - half.noise_um ** 2, 0.0))
    return StructureProfile(tuple(centers.tolist()), tuple(means.tolist()), noise_um, left)
