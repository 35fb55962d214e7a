"""The recursive estimator: one state for what the rig does between frames, one update a frame.

Shaped as a Kalman filter is (filterpy's ``KalmanFilter``): the state ``x`` and its covariance
``P``, ``predict(t)`` moves both to a frame's time with each state's declared rate of change
(settings.py), ``update(frame, reference)`` fuses the frame's gray values (and the grating, where it
is fused) and returns the frame's :class:`FrameEstimate`, made once and frozen. The update is the
iterated (Gauss–Newton) form, with robust reweighting as the measurement's outlier model, in one
compiled call (kernel.py). A batch is the same recursion over a recording's frames
(:func:`track`), so live and batch cannot disagree.

Flags come from one test. The minimum of the update's cost is the innovation's χ² (kernel.py); a
frame whose χ² is beyond its quantile at the declared false-alarm rate has met something the
prediction did not allow for. The families of states that may jump (the light switched, the camera
knocked, the stage jerked) are then ranked by their score test of the innovation (``_ranked``) and
the most evident tried, as the interacting-multiple-model filter weighs its modes: the state with
that family's jump added to its prediction is updated again, and the jump that brings the
innovation back within its quantile is taken (the state learned it; the frame's
``mode`` names it). A frame no jump explains is flagged, its reason the family whose jump explained
most. The bound is the posterior σ of position with every nuisance in the state: where the frames
cannot see a state (the camera's place, a lens's slide, without the grating), the bound carries
its uncertainty, and once that uncertainty outweighs the frame's own noise floor the frames are
flagged with the family that carries it.

Grating modes: ``"check"`` (read, not fused: each frame's position is the image's own, tested
against the grating at the same false-alarm rate, flagged ``scale`` when they disagree; the recursion
goes on from the frame's account with the grating where the image's was refuted: ``_carried``),
``"fuse"`` (a second measurement of the carriage: the camera's place and the lens's lever are
learned against it, the ``--trim`` of the command line), ``"none"`` (no grating read).
"""

from __future__ import annotations

import bisect
import copy
import math
from collections import deque
from typing import TYPE_CHECKING, Callable, NamedTuple

import numpy as np

from graytrack.core.adequacy import FRAME_GAIN_RATE, LIGHT_PROFILE
from graytrack.core.chi2_curve import Chi2Curve
from graytrack.core.compression import stream_bound_factor, stream_chi2_spread
from graytrack.core.errors import TrackingError
from graytrack.core import repeats
from graytrack.core.estimator import kernel
from graytrack.core.estimator.kernel import (S_GAIN, S_LIGHT, S_POSTERIOR, S_REJECTED, S_WEIGHED, U_DT, U_FLICKER,
                                             U_GRATING_W, U_GRATING_Z, U_LEVEL, U_LIGHT, U_POSTERIOR, U_PREDICT, U_WARM)
from graytrack.core.estimator.light_modes import LightModes
from graytrack.core.estimator.commands import StageCommands
from graytrack.core.estimator.flat_field import FLAT_FIELD, FlatField, calibration_flat_field
from graytrack.core.estimator.mount import SHOWN_ACCELERATION, SHOWN_BEYOND, MountWatch, Step, step_test
from graytrack.core.estimator.print_map import PrintMap
from graytrack.core.estimator.print_origin import PrintOrigin
from graytrack.core.estimator.sensor_map import SensorMap
from graytrack.core.estimator.settings import EstimatorSettings
from graytrack.core.estimator.shape_contest import Rival, ShapeContest
from graytrack.core.estimator.state import (A1, A2, B, BAND, BD, BE, BH, BL, BR, BW, C, D, FC, FR, FS, G, L, M, N_STATE,
                                            OFS, SK, SKR, STATE, T, V, X)
from graytrack.core.frame_tables import FrameTables
from graytrack.core.kernels import TableEvaluator
from graytrack.core.models.fourier import FourierModel
from graytrack.core.period_rival import repeats as repeats_each_period
from graytrack.core.quantiles import chi2_isf, normal_isf

if TYPE_CHECKING:
    from graytrack.core.recording import Recording
    from graytrack.core.tracking import TrackResult

GRATING_MODES = ("check", "fuse", "none")
CALIBRATION_PRINT_MAP = "print_map"  # the model's info key for the print's map its calibration learned
CALIBRATION_SURVEY_SIGMA = 3.0  # σ beyond which calibration's own sweep lands a sample on the print (_survey): a
# speck a few % deep, 2-3 σ of a sample's noise, lands by a run's own test only by chance, and a steady run then
# learned what its calibration had not; a candidate is kept only where the motion and its evidence decide it a mark
CALIBRATION_ERROR = "estimator_error_profile"  # ... and for the model's own error as the estimator errs with it
# the families a flag may name as carrying the position's bound, with their states (_carrier)
CARRIERS = (("geometry", (C, T)), ("magnification", (M, L)), ("light", (G, OFS, A1, A2, FC, FS) + BAND),
            ("focus", (B, FR)))
# frames whose row mean the estimator computes compiled as they come (the cameras' and the recordings' types);
# any other is made float64 first
FRAME_TYPES = frozenset(np.dtype(kind) for kind in (np.uint8, np.uint16, np.float32, np.float64))
ACQUIRE_GRID_PER_PERIOD = 64  # grid positions a period when a frame is placed from nothing (a 64th of a period
# is well inside Gauss–Newton's quarter-period reach)
FLICKER_ROUNDING = 1e-9  # a change of the flicker's cosine or sine over an interval below this is the phase's own
# rounding (frames at a whole number of the flicker's cycles apart, 1e-12 at a minute): none, and the flicker's parts
# stay untied to the light, costing its solve nothing
FAILED_TO_REACQUIRE = 3  # frames in a row not placed before the next is placed from nothing again
# Families whose states may jump between two frames, and the states that jump with them.
# (a lamp switched brings its own flicker: the light's jump frees the flicker's parts too, read through the gain)
JUMPS = {"light": (G, OFS, FC, FS), "field": (A1, A2), "focus": (B,), "magnification": (M,), "geometry": (C, T),
         "motion": (V,)}
AGREED_GRID = 33  # positions over half a period where too many samples fail for the sensor's map (_agreed): a
# 64th of a period apart, well inside Gauss–Newton's quarter-period reach from the one chosen; as many again
# within a step of it
AGREED_ROUNDS = 3  # light fits per position, each from the samples the last one left within the test
SEARCHED = 2  # families tried with their jump on a frame that fails the test, most evident first (_ranked): the
# families that mimic each other on one frame come in pairs (the light's shape and a shift over less than a
# period; the stage's jerk and the camera's place without the grating), so the one that moved ranks first or second
BAND_GRID = 16  # a band's entering edges searched a sixteenth of the field apart (its solve reaches a step)
EDGE_RUN = 3  # samples at a row's end beyond their noise on one side: a band's edge entering (by chance: 0.4 % a frame)
BAND_SHARPEST = 1.0 / 64.0  # of the field: a band's penumbra at least this soft (a pixel and a half of a hundred:
# a shadow's edge on the print is as sharp as the optics make it, a veil's on the window far softer), a bound of its
# solve: a band barely in view tells its penumbra little, and its solve would otherwise take it sharp past nought
BAND_HELD_TRAVEL = 4.0  # of a band's penumbra (its σ): the print's travel under a band that holds its place on the
# pixels, after which the position and its edges no longer trade (_band_held)
BAND_HAZIEST = 0.5  # of the light a band takes, the most it scatters back (a veil: a tenth)
BAND_SLIP = 1e-4  # mm/s: how fast a band the print carries may slip against it (none: a mark on the print; a
# speed's own variance kept apart from the stage's velocity's, so that the two are not one state twice in a solve)
BAND_BEYOND = 10.0  # fields beyond the end an edge out of view is put (a veil's: its erf there is 1 to 1e-20)
STROKE_MARGIN_MM = 1.0  # how far beyond its calibrated stroke a stage may be placed (an overshoot at either end):
# a place a whole number of periods off that would put any frame of the run further out is not the frame's
MOUNT_BLIND = ("light", "field", "band", "focus", "magnification")  # jumps after which the mount's window starts anew
LIGHT_JUMPS = ("light", "field")  # the jumps a band entering may be taken for on its first frame (_banded)
REASON = {"light": "light", "field": "light", "band": "light", "geometry": "geometry", "motion": "geometry",
          "focus": "focus", "magnification": "magnification"}


class _Figures(list):
    """A solve's figures (kernel.S_* before kernel.S_GAIN) as plain numbers, read every frame, with the unread
    states' gains on the states solved beside them (``gains``, of the solve's array: read only where a jump's or a
    carried account's posterior is embedded, and valid until the arrays it answered in are solved into again; made
    when read, for most solves never need it)."""

    __slots__ = ("stats",)
    stats: np.ndarray

    @property
    def gains(self) -> np.ndarray:
        return self.stats[S_GAIN:]


class FrameEstimate(NamedTuple):
    """One frame's estimate, made once and immutable (a named tuple: a frame's record costs a
    microsecond). Figures are NaN where they do not exist; ``crlb_mm`` is the posterior σ of position
    with every nuisance (the bound), ``floor_mm`` the frame's own noise floor."""

    t: float
    x_mm: float
    crlb_mm: float
    floor_mm: float
    locked: bool
    rms_gray: float
    chi2: float  # residual per sample in the calibration's level
    test: float  # the innovation's χ² over its quantile at the false-alarm rate (> 1: failed)
    rejected_px: int
    iterations: int
    gain: float
    offset_gray: float
    focus_px2: float  # NaN unless the blur moved beyond its σ at the false-alarm rate
    focus_sigma_px2: float
    stretch: float
    stretch_sigma: float
    place_mm: float
    place_sigma_mm: float
    mode: str  # the family whose jump this frame took ("" none; two of one cause jumped together: "light+field")
    repeated: bool  # the driver delivered the last image again (core/repeats.py): set aside, no position
    stale: bool
    stale_reason: str
    message: str
    state: tuple[float, ...]  # every state (state.py's order) and its σ
    sigma: tuple[float, ...]
    slide_mm: float = math.nan  # without the grating: what the lens's slide adds to the bound (in crlb_mm)


_NOT_ASKED = (math.nan, math.nan, math.nan, math.nan, None, 0.0)  # (Estimator._model_variance's cache, empty)


def _legendre(n_rows: int, n_pixels: int) -> tuple[np.ndarray, np.ndarray]:
    u = np.tile(np.linspace(-1.0, 1.0, n_pixels), n_rows)
    return np.ascontiguousarray(u), np.ascontiguousarray(1.5 * u * u - 0.5)


def _quantile(z: float, dof: float) -> float:
    """χ²(dof)'s upper quantile at the standard normal's ``z`` (Wilson–Hilferty: within 1 % from 10 dof)."""
    k = max(dof, 1.0)
    c = 2.0 / (9.0 * k)
    return k * (1.0 - c + z * math.sqrt(c)) ** 3


def _model_error(info: dict, mapped: dict | None = None) -> tuple[list[float], list[float], float]:
    """(edges, ratios, global ratio) of the model's own error on its calibration frames over their
    bound (core/adequacy.py): the local profile where calibration measured one, else the whole; ``mapped``: what
    remains of it with its error map taken out (calibration_error's ``map``), where the map is read. Each ratio is
    kept as the error power beyond the floor's (ratio² − 1, at least 0): what :meth:`Estimator._model_share`
    reads a frame."""
    from graytrack.core.compression import judged_factor

    # the estimator's own where its calibration measured it (calibration_error: over its floor, a stream's widening
    # in it), else today's tracking's
    own = mapped or info.get(CALIBRATION_ERROR)
    profile = own or info.get("calibration_error_profile") or {}
    whole = float(own["whole"]) if own else float(info.get("calibration_error_ratio") or 1.0) / judged_factor(info)
    edges = np.asarray(profile.get("edges_mm", []), dtype=np.float64)
    ratios = np.asarray(profile.get("ratio", []), dtype=np.float64)
    if edges.size != ratios.size + 1:
        edges, ratios = np.zeros(0), np.zeros(0)
    whole = max(whole, 1.0)
    return edges.tolist(), [max(ratio * ratio - 1.0, 0.0) for ratio in ratios.tolist()], whole * whole - 1.0


def _persistence_curve(info: dict, mapped: dict | None = None) -> tuple[list[float], list[float]] | None:
    """(distances, shares) of what persists of a frame's error against the grating over a window that travelled
    that far (:func:`calibration_error` ``persist``; ``mapped``: of what its error map leaves, where the map is read),
    from all of it at rest; None where calibration measured none."""
    measured = (mapped or info.get(CALIBRATION_ERROR) or {}).get("persist")
    if not measured or not measured.get("distance_mm"):
        return None
    return [0.0] + [float(d) for d in measured["distance_mm"]], [1.0] + [float(p) for p in measured["share"]]


def _interpolated(x: float, xs: list[float], ys: list[float]) -> float:
    """``ys`` at ``x`` along the increasing ``xs``, linearly between them and held beyond either end (np.interp's
    answer for one number, without its conversion of the lists to arrays: a tenth of a frame's update)."""
    k = bisect.bisect_right(xs, x)
    if k <= 0:
        return ys[0]
    if k >= len(xs):
        return ys[-1]
    x0, y0 = xs[k - 1], ys[k - 1]
    return (ys[k] - y0) / (xs[k] - x0) * (x - x0) + y0


def calibration_level(model: FourierModel) -> float:
    """The χ² per sample the calibration's own frames left: what a frame's residual is judged against."""
    rmse = float(model.info.get("calibration_rmse_gray", model.noise_gray or 1.0))
    return float(model.info.get("calibration_chi2", (rmse / (model.noise_gray or 1.0)) ** 2))


class _Layout(NamedTuple):
    """The active states and each jump family's states by their place among them, as the compiled score test
    takes them: (kind, i, j), kind 0 one state, 1 two, 2 the motion (the position and the velocity); with each
    family's degrees of freedom and room for its statistic."""

    idx: np.ndarray
    families: list
    rows: np.ndarray
    dof: list
    statistics: np.ndarray


def _layout(idx: np.ndarray) -> _Layout:
    place = {state: i for i, state in enumerate(idx.tolist())}
    # (a family jumps in the states it has here: one row has no turn, a checked grating no camera's place)
    families = [(family, [place[X], place[V]] if family == "motion" else
                 [place[state] for state in states if state in place])
                for family, states in JUMPS.items() if any(state in place for state in states)]
    rows = np.array([[2 if family == "motion" else len(where) - 1, where[0], where[-1]]
                     for family, where in families], dtype=np.int64).reshape(-1, 3)
    dof = [1 if family == "motion" else len(where) for family, where in families]
    return _Layout(idx, families, rows, dof, np.zeros(len(families)))


class _Bands(NamedTuple):
    """The shapes a band entering is searched among: each one's edges and softness (mm along the target from the
    ROI's centre) and its light lost at every sample for a depth of 1; the field's ends."""

    left: np.ndarray
    right: np.ndarray
    edge: np.ndarray
    band: np.ndarray  # (shapes, samples)
    square: np.ndarray  # its square
    lo: float
    hi: float


_BANDS_MADE: dict[bytes, _Bands] = {}  # the shapes by the field they were made over (_band_shapes)


def _band_shapes(u: np.ndarray) -> _Bands:
    """Bands over the field ``u`` (mm): left edges a sixteenth of the field apart from a quarter field before it,
    each a quarter, a half or the whole field wide or wider than all of it (a veil's edge), and right edges alone
    (a veil from the left), each with a sharp and a soft penumbra (a sixteenth, a sixth of the field). Narrower
    marks are the sensor's map's and the print's (a speck, a scratch), or the robust weights' (a thin cable).
    Made once per field and shared, read-only, by every estimator over it (a millisecond each, paid by every
    command's start and every model the daemon installs)."""
    key = np.ascontiguousarray(u, dtype=np.float64).tobytes()
    made = _BANDS_MADE.get(key)
    if made is None:
        made = _BANDS_MADE[key] = _bands_over(u)
        for array in (made.left, made.right, made.edge, made.band, made.square):
            array.flags.writeable = False
    return made


def _bands_over(u: np.ndarray) -> _Bands:
    from scipy.special import erf

    lo, hi = float(u.min()), float(u.max())
    field = max(hi - lo, 1e-9)
    step = field / BAND_GRID
    far = BAND_BEYOND * field
    shapes: list[tuple[float, float, float]] = []
    for softness in (field / 16.0, field / 6.0):
        for start in np.arange(lo - 0.25 * field, hi, step).tolist():
            shapes += [(start, start + width * field, softness) for width in (0.25, 0.5, 1.0)]
            shapes.append((start, hi + far, softness))
        shapes += [(lo - far, end, softness) for end in np.arange(lo + step, hi + 0.25 * field, step).tolist()]
    left, right, edge = (np.array(column) for column in zip(*shapes))
    scale = np.sqrt(2.0) * edge[:, None]
    band = 0.5 * (erf((u[None, :] - left[:, None]) / scale) - erf((u[None, :] - right[:, None]) / scale))
    return _Bands(left, right, edge, np.ascontiguousarray(band), np.ascontiguousarray(band * band), lo, hi)


class Estimator:
    """The recursive estimator bound to one calibrated model.

    ``grating``: how a grating reading is used (module docstring). ``robust``: robust reweighting on.
    ``settings``: the declared rates and levels (settings.py). ``survey_sigma``: where not nought, every sample a
    placed frame leaves beyond that many σ lands on the print (:meth:`_survey`: calibration's own sweep).
    ``flat_field``: the sensor's pattern its frames are seen through (flat_field.py), where not the model's own."""

    def __init__(self, model: FourierModel, settings: EstimatorSettings | None = None, grating: str = "check",
                 robust: bool = True, axis_px: float | None = None, stage_phases: np.ndarray | None = None,
                 survey_sigma: float = 0.0, flat_field: FlatField | None = None):
        if not model.is_calibrated:
            raise TrackingError("the model has no coefficients: calibrate it first")
        if grating not in GRATING_MODES:
            raise TrackingError(f"grating mode must be one of {', '.join(GRATING_MODES)}, got {grating!r}")
        self.model, self.grating, self.robust = model, grating, robust
        self.survey_sigma = float(survey_sigma)
        self.settings = settings = settings or EstimatorSettings()
        if axis_px is not None:
            # the lever's size is what the bound needs (a declared axis and a prior of that size carry the same slide
            # σ: the stretch times it); its sign would only pick the slide's direction, which no frame corrects here
            settings = self.settings = settings.replace(lever_prior=abs(float(axis_px)))
        self.z_alpha = normal_isf(settings.false_alarm)
        self.z_two = normal_isf(settings.false_alarm / 2.0)
        self.z_two2 = self.z_two ** 2  # (its square: read every frame)
        self.grating_var = settings.grating_sigma ** 2  # (the grating's reading's variance, mm²: read every frame)
        tables = FrameTables.of(model)
        self.evaluator = TableEvaluator(tables)
        self.model_args = self.evaluator._args
        n_values = model.n_rows * model.n_pixels
        self.n_values = n_values
        target = model.target_offset().reshape(-1)
        self.t_rel = np.ascontiguousarray(target - target.mean())
        rows = np.repeat(np.arange(model.n_rows) - 0.5 * (model.n_rows - 1), model.n_pixels)
        self.r_rel = np.ascontiguousarray(rows.astype(np.float64))
        self.b1, self.b2 = _legendre(model.n_rows, model.n_pixels)
        self.mask = np.ones(n_values) if model.pixel_weight is None else \
            np.ascontiguousarray(model.pixel_weight, dtype=np.float64).reshape(-1)
        # the sensor's rough pattern calibration's sweep measured (flat_field.py): every frame is seen through it,
        # each sample's weight its gain's square (its noise as the camera read it, scaled), and the calibration's
        # frames leave a level, a course along the stroke and a spread of their own with it out
        self.flat = flat_field if flat_field is not None else FlatField.from_info(model.info, n_values)
        if self.flat is not None:
            self.mask = np.ascontiguousarray(self.mask * self.flat.gain ** 2)
        noise = model.noise()
        self.noise = np.array([noise.read_var + noise.quant_var, noise.shot_gain, noise.dark_gray])
        self.chi2_calibration = calibration_level(model) if self.flat is None else self.flat.level
        if not (math.isfinite(self.chi2_calibration) and self.chi2_calibration > 0):
            raise TrackingError(f"the model's calibration χ² is {self.chi2_calibration:g}: recalibrate")
        self.chi2_curve = Chi2Curve.from_info(model.info) if self.flat is None else self.flat.curve
        # Where the image places the carriage at each place as calibration measured it against the grating (its error
        # map, calibration_error): every sample is evaluated there (kernel.U_MAPPED), so that the state is the
        # carriage's place, and the bound keeps what the map leaves. Read and checked from the first frame; from the
        # image alone, which places a frame up to whole periods, once the run's travel leaves it one place (_mapping);
        # not fused, where the grating and the latch's skew take up what the image misses at a place.
        mapped = (model.info.get(CALIBRATION_ERROR) or {}).get("map" if grating == "check" else "map_alone") \
            if grating != "fuse" else None
        self._error_map = None if not mapped else (
            [float(x) for x in mapped["x_mm"]], [float(e) for e in mapped["error_mm"]])
        # (from the image alone, before its map is read, the error its own pass measured: its states err otherwise)
        self._plain_error = _model_error(model.info, (model.info.get(CALIBRATION_ERROR) or {}).get("alone")
                                         if grating == "none" else None)
        self._mapped_error = _model_error(model.info, mapped) if mapped else self._plain_error
        # From the image alone a model that repeats once a period places a frame up to whole periods (its origin
        # is the acquisition's pick): what calibration keeps along the stroke (its χ² curve, its model's error) is
        # read at every place the frame may be, those a whole number of periods away that keep each frame the run
        # has placed within the stroke (_places).
        self._folded = grating == "none" and repeats_each_period(model)
        self._mapped_at = math.nan if self._folded else 0.0  # (the map's place less the state's, once it is known)
        self.model_error = self._plain_error if self._folded else self._mapped_error
        self._reach = [math.inf, -math.inf]  # the run's placed positions, lowest and highest (mm; a new list each move)
        # (_model_share's last question and answer, _model_variance's: each with the run's reach it was asked under,
        # a new list whenever the reach changes)
        self._share_at: tuple[float, list[float] | None, float] = (math.nan, None, 0.0)
        self._variance_at: tuple[float, float, float, float, list[float] | None, float] = _NOT_ASKED
        # a lossy stream's χ² scatters as fewer samples', and so does noise the samples share (its calibration's
        # frames measured it: core/chi2_curve.py frame_spread); with the rows' offsets taken out of each frame (below),
        # as it scatters without them, against the level without them
        banding = model.n_rows > 1 and float(model.info.get("row_offset_gray") or 0.0) > 0.0
        shared = model.info.get("row_chi2_spread") if banding else \
            model.info.get("frame_chi2_spread") if self.flat is None else self.flat.spread
        self.spread = max(stream_chi2_spread(model.info), float(shared or 1.0))
        self._test_quantiles: dict[float, float] = {}  # χ²'s quantile by the samples a frame used (_test)
        if banding:
            self.chi2_calibration *= float(model.info.get("row_chi2_share") or 1.0)
        self.bound_factor = stream_bound_factor(model.info)
        # the readout's limits: where the run's recording states its camera's (settings.for_recording), those; else
        # calibration's camera's, as the model states them
        limits = model.info.get("sensor_range_gray") or (-math.inf, math.inf)
        lo = settings.sensor_floor_gray if math.isfinite(settings.sensor_floor_gray) else float(limits[0])
        hi = settings.sensor_ceiling_gray if math.isfinite(settings.sensor_ceiling_gray) else float(limits[1])
        self.sensor_range = (lo, hi) if robust and (math.isfinite(lo) or math.isfinite(hi)) else None
        pitch = model.pixel_pitch_mm
        rates = np.zeros(N_STATE)
        # the light's gain and offset hold or drift, a mode the frames decide (light_modes.py); with no switching, one
        # mode: the drifting rates throughout. Drifting, the gain walks at least as fast as calibration's frames showed
        # it walk from frame to frame (a camera hunting its exposure: core/adequacy.py frame_gain_rate), whose steps
        # held to the declared drift went into the position
        gain_rate = max(settings.gain_rate, float(model.info.get(FRAME_GAIN_RATE) or 0.0))
        self.light = LightModes(settings.light_switch_rate,
                                (settings.gain_rate_holding ** 2, settings.offset_rate_holding ** 2),
                                (gain_rate ** 2, settings.offset_rate ** 2))
        rates[G], rates[OFS] = (math.sqrt(rate) for rate in self.light.rates())  # (each frame's mode's: _advance)
        rates[A1] = rates[A2] = settings.field_rate
        # the lamp's flicker at twice the mains moves the frame's light on from frame to frame (kernel.predict), at
        # the phase of the frame's time from the estimate's start (_advance)
        self._flicker = settings.flicker_prior > 0.0 and settings.mains_hz > 0.0
        self._flicker_omega = 4.0 * math.pi * settings.mains_hz  # rad/s
        self._flicker_t0 = 0.0
        rates[FC] = rates[FS] = settings.flicker_rate if self._flicker else 0.0
        rates[B] = settings.focus_rate
        rates[FR] = settings.focus_drift_rate  # (the blur's rate: its change white, kernel.predict)
        rates[M] = settings.stretch_rate
        rates[C] = settings.place_rate
        rates[T] = settings.tilt_rate
        rates[SK] = settings.skew_rate
        rates[SKR] = settings.clock_drift_rate  # (the latch's rate: its change white, kernel.predict)
        rates[BD], rates[BL], rates[BR], rates[BE], rates[BH] = (
            settings.band_rate_depth, settings.band_rate_edge, settings.band_rate_edge, settings.band_rate_soft,
            settings.band_rate_haze)
        rates[BW] = settings.band_acceleration  # (the band's speed: white acceleration, kernel.predict)
        active = [X, V, G, OFS, A1, A2, B, M]
        # the rates of the blur's and the latch's drifts: states (with a variance) only where they may drift, and
        # never solved (state.py UNREAD: conditioned on the states solved, kernel.conditioned)
        self._drifts = frozenset(([FR] if settings.focus_drift_prior > 0.0 else []) +
                                 ([SKR] if grating == "fuse" and settings.clock_drift_prior > 0.0 else []))
        # The stage follows its commanded path within its jitter (kernel.predict; the path bends where commanded,
        # _advance): where the image places the carriage (the grating read and checked, or none), that path carries
        # the velocity from frame to frame instead of each frame's pull. Fused, the grating reads the carriage at
        # every frame, and at a constant speed its latch's skew and the velocity are one product (x − v·skew): a
        # velocity the path holds leaves the skew to take what the image's model misses at each place, so there
        # the stage may accelerate anywhere, and the velocity follows the frames.
        # (the jitter is a state no sample sees apart from the position: never solved, conditioned on the states
        # solved after each update, kernel.conditioned and kernel.embed)
        self.on_path = grating != "fuse" and settings.stage_jitter > 0.0
        if self.on_path:
            rates[D] = settings.stage_jitter
        self.rates2 = rates ** 2
        if grating != "check":  # checked, the grating judges the place and the slide; else the place is a state
            active.append(C)
        # Read and checked, the place is held where it is (no frame tells it from the carriage) until the grating
        # refutes the frames by one offset from the first of a run of refutations: a knock (_steady_step). The
        # grating's disagreement with each frame's own account (mm) and its variance, over those first frames:
        self._step_frames = max(int(settings.place_step_frames), 1)
        self._refutations: deque = deque(maxlen=self._step_frames)
        self._spoiled = False  # whether the run of refutations followed a frame off its test or a jump
        # The lens's lever (its axis from the ROI's centre) is a state where the grating is fused, which reads the
        # carriage against the image. Without it no frame tells the lever: the image places x + L·m, and solved, the
        # lever was narrowed by whatever the stage's path said the carriage was, so that a stretch the frames took
        # (a magnification jump after a shadow's pass) put the path's error into a lever 10 mm off and the position
        # 37 µm off under a 7 µm bound, unflagged. There it is held at its prior, a parameter the bound considers
        # (_slide_variance), never solved. (An ROI on the lens's axis: no lever.)
        if grating == "fuse" and settings.lever_prior > 0.0:
            active.append(L)
        if grating == "fuse":  # fused, the grating's own latch against the exposure is one too, and its drift
            active.append(SK)
        if model.n_rows > 1:
            active.append(T)
        self.idx = self.idx_plain = np.array(sorted(active), dtype=np.int64)
        # With a band in view its states too, and the geometry held (the camera's place, the lens, the latch:
        # over less than a period a band's edges and a shift trade, and what a band's frames would teach the
        # place stays after the band has gone, which no frame without the grating could undo).
        self.idx_band = np.array(sorted((set(active) - {C, L, M, T, SK}) | set(BAND)), dtype=np.int64)
        # Read and checked, the lever is learned where the grating reads the carriage: in the account the recursion
        # carries where the image's own was refuted (_carried). A lens whose magnification drifts slides the image
        # by the lever times the stretch the frames see, which the grating then refutes while it grows; learned
        # there, the frames' own accounts take the slide out. Solved in every frame's own update it would be
        # narrowed by the stage's path instead, and take up what a mark or a veil stretches the image by.
        self.idx_carried = np.array(sorted(set(active) | {L}), dtype=np.int64) \
            if grating == "check" and settings.lever_prior > 0.0 else self.idx_plain
        self._active = frozenset(active)
        self._jumping = self._active | ({FC, FS} if self._flicker else set())  # (the states a jump widens)
        # without the grating what no frame sees of the carriage against the image: the lens's slide, and with it the
        # camera's place on the carriage (_stated)
        self._slide_states = np.array([state for state in (M, L) if state in active], dtype=np.int64)
        self._band_states = np.array(BAND, dtype=np.int64)
        self._unseen_states = np.array([state for state in (M, L, C, T) if state in active], dtype=np.int64)
        # The light along the stroke as calibration's frames read it (core/adequacy.py light_profile): the gain a frame
        # sees is carried from the last frame's place to its own by it (_carry_light), the lamp's drift apart. Not from
        # the image alone, which places a frame up to whole periods and would read the light of another place.
        profile = model.info.get(LIGHT_PROFILE) if grating != "none" else None
        self._light_along = None if not profile else (
            [float(x) for x in profile["x_mm"]], [math.log(float(g)) for g in profile["gain"]])
        # a light calibration saw walk from frame to frame (a camera hunting its exposure): what it carries of the
        # position is the rig's own precision, as a frame solved with its light free states it (_stated)
        self._walking_light = np.array([G, OFS], dtype=np.int64) if gain_rate > settings.gain_rate else None
        self._carriers: dict[bool, list] = {}  # (_carrier's families over each set of states solved)
        self.idx_appearance = np.array([state for state in (X, V, G, OFS, A1, A2, B) if state in active and
                                        not (state == V and self.on_path)],
                                       dtype=np.int64)
        self.scratch = np.zeros((6, n_values))
        self.rho = np.ones(n_values)
        self._row_masks: dict[int, np.ndarray] = {}  # the pixel mask over the rows a frame averages, by rows
        self.stats = np.zeros(kernel.N_STATS)
        self.update_errors = 0  # frames whose update failed on numbers that were not finite (update)
        # the light's shape at the first frames, as calibrated against changed since (shape_contest.py): the rival
        # followed beside this estimator, whether this one is a contest's (its frames' evidence then kept) and
        # whether a contest was held already
        self._contest: ShapeContest | None = None
        # (read or fused, the grating places the carriage whatever the shape: the contest is the image's alone)
        self._contested = grating != "none" or settings.shape_contest_frames <= 0 or \
            (settings.field_changed_prior <= settings.field_prior and
             settings.stretch_changed_prior <= settings.stretch_prior)
        self._weighing = False
        self._updating = False  # (within a frame's update: a start made there is the update's own)
        self.evidence = math.nan  # the last frame's log-likelihood under this estimator (while weighed)
        self.s = np.zeros(N_STATE)
        self.P = np.zeros((N_STATE, N_STATE))
        # a frame's own arrays, made once: its gray values, their mask, the main update's answer and the σ
        self._y = np.zeros(n_values)
        self._masked = np.zeros(n_values)
        self._seen = None if model.pixel_weight is None else np.asarray(model.seen(), dtype=np.float64).reshape(-1)
        self._answer = (np.empty(N_STATE), np.empty((self.idx.size, self.idx.size)), np.empty(kernel.N_STATS))
        self._sigma = np.empty(N_STATE)
        self._P_next = np.zeros((N_STATE, N_STATE))  # where the main update makes the posterior covariance
        # the update's constants, as the kernel takes them (kernel.U_*, kernel.PX_*): a frame sets the grating's two
        self.pixels = np.ascontiguousarray(np.stack([self.t_rel, self.r_rel, self.b1, self.b2]))
        self.params = params = np.zeros(kernel.N_PARAMS)
        params[[kernel.U_READ, kernel.U_SHOT, kernel.U_DARK]] = self.noise
        params[kernel.U_PITCH], params[kernel.U_PERIOD] = model.pixel_pitch_mm, model.period_mm
        params[kernel.U_ROBUST] = 1.0 if robust else 0.0
        params[kernel.U_CORE], params[kernel.U_CUT] = settings.core_sigma, settings.cut_sigma
        params[kernel.U_ITERATIONS], params[kernel.U_TOLERANCE] = int(settings.max_iterations), settings.tolerance
        # The stage's acceleration anywhere (where its commands are known, _advance): on its path, a phase of a
        # profile no one told the estimator, held over an interval; fused, what frees the velocity to follow the
        # frames, white within it (kernel.predict: held, a velocity read that well from the positions rings).
        anywhere = settings.acceleration ** 2
        params[kernel.U_ACCELERATION], params[kernel.U_ACCELERATION_WHITE] = (anywhere, 0.0) if self.on_path else \
            (0.0, anywhere)
        params[kernel.U_RATES:] = self.rates2
        # an offset each row draws afresh every frame, as calibration measured it (core/adequacy.py row_offset_gray):
        # eliminated from each frame's solve, so that a row's banding moves no state
        if banding:
            params[kernel.U_ROW_LENGTH] = model.n_pixels
            params[kernel.U_ROW_PRECISION] = 1.0 / float(model.info["row_offset_gray"]) ** 2
        elif float(model.info.get("frame_offset_gray") or 0.0) > 0.0:
            # an offset the whole frame draws afresh, as calibration measured it (a one-row sensor's line offset at
            # each readout: core/adequacy.py frame_offset_gray), taken out of each frame as a row's is
            params[kernel.U_ROW_LENGTH] = n_values
            params[kernel.U_ROW_PRECISION] = 1.0 / float(model.info["frame_offset_gray"]) ** 2
        self.t_last: float | None = None
        self.last_frame: np.ndarray | None = None
        self.dt_last = 0.0
        self._xi_last = math.nan  # the image's position at the last frame the maps learned from (mm)
        # read and checked: the grating less the position over the last frames, with the frames' own variance
        # (_disagreeing)
        self._check_length = max(int(settings.check_window), 1)
        self._check: deque[tuple[float, float]] = deque()
        self._check_places: deque[float] = deque()  # (where each of them was placed, mm)
        self._check_sum = self._check_var = 0.0
        # what of a frame's error against the grating persists over the distance a window travels (calibration's)
        self._persist = _persistence_curve(model.info, mapped)
        self._drift_only = False  # the frame's flag is the window's alone (_estimate)
        self._lens_var, self._lens_m = 0.0, 0.0  # the stretch a filter at the lens's fastest rate holds (_lens)
        self._t_start = 0.0  # when the estimate started (s: the camera's creep is counted from it, _stated)
        self._checked = math.nan  # the grating's reading of the frame being updated, where it is read and checked
        self.failed = 0
        self.started = False
        mid = 0.5 * (float(model.stroke_range_mm[0]) + float(model.stroke_range_mm[1]))
        self.mean_gray = float(np.mean(self.evaluator.evaluate(np.array([mid]))[0]))  # the light's scale, gray
        mean = max(abs(self.mean_gray), 1.0)
        # the sensor's side: a gain and an offset per sample, learned where something lands (sensor_map.py)
        self.sensor = SensorMap(n_values, self.noise, self.chi2_calibration,
                                normal_isf(settings.false_alarm / (2.0 * n_values)),
                                np.array([settings.map_jump_gain ** 2, (settings.map_jump_offset * mean) ** 2,
                                          settings.map_rate_gain ** 2, settings.map_rate_offset ** 2]), mean,
                                settings.map_most, int(settings.map_reach_px), model.n_pixels, settings.map_hold)
        # the print's side: a reflectance change per place along the target, learned where something lands
        # (print_map.py)
        self.print_origin: PrintOrigin | None = None  # (calibration's marks telling the period: print_origin.py)
        self._origin_periods: int | None = None  # the print's coordinates ahead of the run's, once the marks told
        self.print_map = PrintMap.of(model, self.noise, self.chi2_calibration, self.sensor.z2 ** 0.5,
                                     np.array([settings.print_jump ** 2, settings.print_rate ** 2]), mean)
        self._noise_var = np.ones(n_values)
        self._expected = np.zeros(n_values)
        self._zeros = np.zeros(n_values)
        self._printed = False  # whether the frame being updated was seen through the print's map
        self._pinned: np.ndarray | None = None  # the last refuted frame's account with the carriage pinned (_carried)
        flicker = settings.flicker_prior if self._flicker else 0.0
        self.jump_var = {"light": np.array([settings.jump_light, settings.jump_light * mean, flicker, flicker]) ** 2,
                         "field": np.array([settings.jump_field, settings.jump_field]) ** 2,
                         "focus": np.array([settings.jump_focus]) ** 2,
                         "magnification": np.array([settings.jump_stretch]) ** 2,
                         "geometry": np.array([settings.jump_place, settings.jump_turn * pitch]) ** 2,
                         "motion": np.array([settings.jump_motion]) ** 2}
        # a family's score beyond χ²(its states)'s quantile at the false-alarm rate points the innovation its way
        self._score_quantile = {k: chi2_isf(settings.false_alarm, k) for k in (1, 2, 3)}
        # a band's states beyond a jump's (six against the light's two): what a band must explain more by
        self._band_margin = chi2_isf(settings.false_alarm, len(BAND) - 2)
        self._lever_margin = chi2_isf(settings.false_alarm, 1)  # (what the lens's lever must explain more by)
        self._layout = self._layout_plain = _layout(self.idx_plain)
        self._layout_band = _layout(self.idx_band)
        self._unexplained: list[str] = []  # the families tried on the last frame, none of whose jumps explained it
        self._placed_again = False  # a frame of this episode was placed again by its agreeing samples, in vain
        self._band_failed = 0  # frames in a row the band followed did not explain
        # whether anything has changed since the estimate started (a jump taken, a frame failing its test): until then
        # what carries the position's bound is the priors', which the bound states; after, a state's memory carrying
        # it may be a change the frames follow without failing (a veil forming under the light's states), flagged
        self._changed = False
        self._band_missed = 0  # frames in a row that failed with no band followed, since one passed its test
        self._refuted_missed = 0  # ... the grating refuted with no band taken, since one it did not refute (_carried)
        self._last_mode = ""  # the family whose jump the last frame took
        self._band_entered = math.nan  # the image's position where the band followed entered (_band_held)
        # where the band followed stood on its first frame (its edges and penumbra), and whether the print carries it
        # (_band_on_print)
        self._band_edges: tuple[float, float, float] | None = None
        self._band_print = False
        self._bands = _band_shapes(self.t_rel)  # the shapes a band entering is searched among (edges, softness)
        self.params[kernel.U_BAND_SHARPEST] = BAND_SHARPEST * (self._bands.hi - self._bands.lo)
        # without the grating, the camera's place moves only as a step no motion of the stage makes (mount.py)
        # (as fast as the stage is commanded, and no less than its calibration's grating showed it to be)
        # With the stage's commanded phases known (a recording's stage_acceleration_phases), an interval allows what
        # its command asked and what the stage does beyond its commands (no less than its calibration showed); a
        # calibration that did not state its commands showed only the stage's most, commands and all.
        shown = float(model.info.get(SHOWN_ACCELERATION, 0.0) or 0.0)
        most = max(settings.stage_acceleration, shown)
        beyond = model.info.get(SHOWN_BEYOND)
        beyond = most if beyond is None else max(settings.stage_servo, float(beyond))
        # what the stage was commanded to do: where its path bends (the motion's process noise) and, without the
        # grating, what steps the mount's test allows
        self.commands = StageCommands(stage_phases, most, settings.stage_settle)
        self.mount = MountWatch(most, self.z_two, beyond=beyond, commands=self.commands) \
            if grating == "none" else None
        self._warm()
        # the print's own marks as calibration's sweep learned them (calibration_print_map): with the grating the run
        # is placed on the print's coordinates and starts with them known; from the image alone its origin is the
        # acquisition's pick, up to whole periods, and the marks tell which (print_origin.py) before they are read
        calibrated = model.info.get(CALIBRATION_PRINT_MAP)
        try:
            if calibrated and grating != "none":
                self.print_map.restore(calibrated)
            elif calibrated and self._folded:
                finder = PrintOrigin(calibrated, copy.deepcopy(self.print_map), model.period_mm)
                self.print_origin = finder if finder.any else None
        except ValueError:  # (a map another grid made: the print as calibrated, as before such maps were kept)
            self.print_map.reset()

    # ------------------------------------------------------------------ the recursion
    def start(self, x_mm: float, t: float, sigma_mm: float) -> None:
        """The state before the first frame: position ``x_mm`` ± ``sigma_mm``, nuisances at calibration (a start
        given from outside while the first frames' contest runs ends it: the shape as calibrated stands)."""
        if self._contest is not None and not self._updating:
            self._contest = None
            self._weighing = False
        settings, pitch = self.settings, self.model.pixel_pitch_mm
        self.s[:] = 0.0
        self.s[X], self.s[G] = x_mm, 1.0
        prior = np.zeros(N_STATE)
        prior[X] = sigma_mm
        prior[V] = 100.0  # mm/s: any speed the stage can go
        prior[G], prior[OFS] = settings.gain_prior, settings.offset_prior
        prior[A1] = prior[A2] = settings.field_prior
        prior[FC] = prior[FS] = settings.flicker_prior if self._flicker else 0.0
        prior[B] = settings.focus_prior
        prior[FR] = settings.focus_drift_prior if FR in self._drifts else 0.0
        prior[M] = settings.stretch_prior
        prior[C] = settings.grating_sigma
        prior[L] = settings.lever_prior * pitch
        prior[T] = 1e-6
        prior[SK] = settings.skew_prior
        prior[SKR] = settings.clock_drift_prior if SKR in self._drifts else 0.0  # (held at zero where not fused)
        prior[D] = settings.stage_jitter if self.on_path else 0.0  # (the path as unknown as the position and jitter)
        self.P[:] = np.diag(prior ** 2)
        self.t_last = t
        self.started = True
        self._t_start = self._flicker_t0 = t
        self.params[kernel.U_FLICKER:kernel.U_RATES] = (0.0, 0.0, 1.0, 0.0)
        self._changed = False
        self._xi_last = math.nan
        self._check.clear()
        self._check_places.clear()
        self._check_sum = self._check_var = 0.0
        self._lens_var, self._lens_m = float(self.P[M, M]), 0.0
        self.failed = 0
        self._unexplained = []
        self._placed_again = False
        self._band_missed = self._refuted_missed = 0
        self._refutations.clear()
        self._spoiled = False
        self._last_mode = ""
        self.light.reset()
        self._light_rates()
        self._band_off()
        self._reach = [math.inf, -math.inf]
        if self.mount is not None:
            self.mount.reset()
        if self.print_origin is not None:  # placed afresh from the image: its period the acquisition's pick again
            self.print_origin.reset()
            if self._origin_periods is not None:
                self._origin_periods = None
                self.print_map.reset()

    def predict(self, t: float) -> None:
        """State and covariance moved on to time ``t``."""
        dt = self._advance(t)
        kernel.predict(self.s, self.P, dt, self.params.item(kernel.U_ACCELERATION),
                       self.params.item(kernel.U_ACCELERATION_WHITE), self.rates2,
                       self.params[kernel.U_FLICKER:kernel.U_RATES])

    def _advance(self, t: float) -> float:
        """The interval from the last frame's time to ``t`` (s, never negative), ``t`` now the last; the path's
        acceleration's variance over it (``params[U_ACCELERATION]``, mm²/s⁴, held over the interval): where the
        stage's commands are known, what they asked then (its phases, mm/s²) or else how little its path bends
        between them; where they are not, the stage's acceleration anywhere (as set at the start)."""
        last = self.t_last
        if last is None:
            dt = 0.0
        else:
            dt = t - last
            if dt < 0.0:  # (max(dt, 0.0) without the call: the same number, -0.0 and NaN kept as it kept them)
                dt = 0.0
        light = self.light
        if light.switch_rate > 0.0:  # the light predicted in the mode its frames make likelier (light_modes.py)
            was = light.drifting
            if light.advance(dt) != was:
                self._light_rates()
        if self.on_path and self.commands.known:
            asked = self.commands.asked(t - dt, t) if dt > 0.0 else 0.0
            self.params[kernel.U_ACCELERATION] = asked * asked + self.settings.stage_drift ** 2
        if self._flicker:  # the flicker's turn over the interval (kernel.predict)
            phase = self._flicker_omega * (t - self._flicker_t0)
            params = self.params
            cos_new, sin_new = math.cos(phase), math.sin(phase)
            d_cos, d_sin = cos_new - params.item(U_FLICKER + 2), sin_new - params.item(U_FLICKER + 3)
            if abs(d_cos) < FLICKER_ROUNDING and abs(d_sin) < FLICKER_ROUNDING:
                d_cos = d_sin = 0.0  # (a frame rate that samples the flicker at one phase: it never moves the light)
            params[U_FLICKER], params[U_FLICKER + 1] = d_cos, d_sin
            params[U_FLICKER + 2], params[U_FLICKER + 3] = cos_new, sin_new
        self.dt_last, self.t_last = dt, t
        return dt

    def _mapping(self, mapped: tuple[list[float], list[float]], x: float) -> None:
        """The image's place off the error map ``mapped`` (places, errors: mm) at the frame's predicted place ``x``
        (mm), into the update's ``U_MAPPED``. From the image alone the place is known once the run's travel leaves
        the frames one place a whole number of periods from where they were placed (_places): from then on the map
        is read there, the bound keeps what it leaves, and the state moves by what the map says the image erred by
        at the first frame read, so that the state becomes the carriage's place and the image's stays where it was."""
        if self._mapped_at != self._mapped_at:  # (not yet known)
            period = self.model.period_mm
            lo, hi = float(self.model.stroke_range_mm[0]) - STROKE_MARGIN_MM, \
                float(self.model.stroke_range_mm[1]) + STROKE_MARGIN_MM
            low, high = min(self._reach[0], x), max(self._reach[1], x)
            first, last = math.ceil((lo - low) / period), math.floor((hi - high) / period)
            if first != last:
                return
            self._mapped_at = first * period
            self.model_error = self._mapped_error
            self._share_at, self._variance_at = (math.nan, None, 0.0), _NOT_ASKED
            shift = _interpolated(x + self._mapped_at, *mapped)
            self.s[X] -= shift
            self.params[kernel.U_MAPPED] = shift
            if self.mount is not None:  # (the state's step is the map's, not the camera moving on its mount)
                self.mount.reset()
            return
        self.params[kernel.U_MAPPED] = _interpolated(x + self._mapped_at, *mapped)

    def _carry_light(self, along: tuple[list[float], list[float]], before: float, after: float) -> None:
        """The gain (and its variance) carried from the place ``before`` to ``after`` (mm) by the light ``along`` the
        stroke calibration read (places, log gains): the gain is the frame's light, the lamp's level times the light
        at the frame's place."""
        xs, logs = along
        ratio = math.exp(_interpolated(after, xs, logs) - _interpolated(before, xs, logs))
        if ratio != 1.0:
            self.s[G] *= ratio
            self.P[G, :] *= ratio
            self.P[:, G] *= ratio

    def _light_rates(self) -> None:
        """The light's gain and offset predicted at the rates of the mode the frame is in (light_modes.py)."""
        g2, o2 = self.light.rates()
        self.rates2[G], self.rates2[OFS] = g2, o2
        self.params[kernel.U_RATES + G], self.params[kernel.U_RATES + OFS] = g2, o2

    def update(self, frame: np.ndarray, t: float, reference_mm: float = math.nan) -> FrameEstimate:
        """The frame at time ``t`` (mid-exposure) with its grating reading (NaN: none). Over the first frames the
        light's shape as calibrated and as changed are weighed side by side (shape_contest.py): the estimate is this
        estimator's until the rival's evidence takes over, and from then on the rival's (this estimator becomes it)."""
        if not self._contested:
            self._contest_open()
        estimate = self._guarded(frame, t, reference_mm)
        contest = self._contest
        if contest is not None:
            rivals = list(contest.rivals)
            others = [rival.estimator._guarded(frame, t, reference_mm) for rival in rivals]
            verdict = contest.weigh(self.evidence, [rival.estimator.evidence for rival in rivals],
                                    [other.test <= 1.0 for other in others])
            if verdict is not None:
                self._contest = None
                self._weighing = False
                if isinstance(verdict, Rival):  # (the rival that explained the frames becomes this estimator)
                    verdict.estimator._weighing = False
                    self.__dict__.update(verdict.estimator.__dict__)
                    taken = others[rivals.index(verdict)]
                    said = (f"{verdict.what} changed since calibration ({verdict.ratio:.1f} nats of evidence over "
                            f"{int(self.settings.shape_contest_frames) - contest.left} frames): followed as changed")
                    return taken._replace(message=f"{taken.message}; {said}" if taken.message else said)
        return estimate

    def _contest_open(self) -> None:
        """The rivals of the first frames: this estimator as it stands (maps restored, a start given), one family's
        states allowed the priors of a rig changed since calibration in each: the light's shape, the magnification."""
        self._contested = True
        settings = self.settings
        rivals = []
        for what, states, changed in (
                ("the light's shape across the line", (A1, A2),
                 {"field_prior": max(settings.field_changed_prior, settings.field_prior)}),
                ("the magnification", (M,),
                 {"stretch_prior": max(settings.stretch_changed_prior, settings.stretch_prior)})):
            sigma = next(iter(changed.values()))
            if sigma <= getattr(settings, next(iter(changed))):
                continue
            rival = copy.deepcopy(self, {id(self.model): self.model})
            rival.settings = settings.replace(**changed)
            if rival.started:
                for state in states:
                    rival.P[state, state] = max(rival.P.item(state, state), sigma * sigma)
                if M in states:  # (the lens's own filter starts there too)
                    rival._lens_var = max(rival._lens_var, sigma * sigma)
            rival._weighing = True
            rivals.append(Rival(rival, 0.5 * self._score_quantile[len(states)], what))
        self._weighing = bool(rivals)
        self._contest = ShapeContest(rivals, int(settings.shape_contest_frames)) if rivals else None

    def _guarded(self, frame: np.ndarray, t: float, reference_mm: float) -> FrameEstimate:
        """One frame's update (:meth:`update` without the contest)."""
        self.evidence = math.nan
        self._updating = True
        try:
            return self._update(frame, t, reference_mm)
        except np.linalg.LinAlgError as exc:
            # A solve met numbers that are not finite (a covariance gone wrong, a weight no map could give): the
            # frame is not placed and says why, and the estimate starts again from the next frame, rather than
            # carry a state it cannot trust or stop the frame loop that drives it.
            self.failed = FAILED_TO_REACQUIRE
            self.update_errors += 1
            return self._unplaced(t, self.stats, math.nan,
                                  f"the update failed ({exc}); the estimate starts again from the next frame")
        finally:
            self._updating = False

    def _update(self, frame: np.ndarray, t: float, reference_mm: float) -> FrameEstimate:
        if type(frame) is not np.ndarray:  # (an array is its own asarray: the call spared a frame)
            frame = np.asarray(frame)
        last, self.last_frame = self.last_frame, frame
        # (an image again is equal in its first sample too: that one comparison settles nearly every frame)
        if last is not None and last.shape == frame.shape and frame.size and last.item(0) == frame.item(0) and \
                repeats.repeated(frame[None], self.model.noise_gray or 0.0, last)[0]:
            # the image shows where the stage was, its time and grating where it is: no measurement of either
            return self._unplaced(t, self.stats, math.nan, "the driver delivered the last image again", True)
        y_raw, raw_mask = self._prepared(frame)
        if self.started and self.s.item(BE) > 0.0:
            self._band_on_print()
        dt = predict = None
        acquiring = not self.started or self.failed >= FAILED_TO_REACQUIRE
        if not acquiring:
            dt = predict = self._advance(t)  # the prediction to the frame's time, made by the update's own call
            before = self.s.item(X)
            if self.print_map.active:  # ... or first, where the print's map is read at the predicted image
                kernel.predict(self.s, self.P, dt, self.params.item(kernel.U_ACCELERATION),
                               self.params.item(kernel.U_ACCELERATION_WHITE), self.rates2,
                               self.params[kernel.U_FLICKER:kernel.U_RATES])
                predict = None
            if self._light_along is not None or self._error_map is not None:
                # the light carried to the frame's predicted place, and the image's place read off the error map there
                # (the prediction's mean: the path on at its velocity, the last frame's jitter dropped, kernel.predict)
                ahead = self.s.item(X) if predict is None else before + self.s.item(V) * dt - self.s.item(D)
                if self._light_along is not None:
                    self._carry_light(self._light_along, before, ahead)
                if self._error_map is not None:
                    self._mapping(self._error_map, ahead)
        # seen through what sits on the sensor's side and on the print (the frame itself while nothing has landed)
        y, mask = self._through_maps(y_raw, raw_mask, not acquiring)
        if acquiring:
            self._acquire(y, mask, t, reference_mm)
            if self._error_map is not None:
                self._mapping(self._error_map, self.s.item(X))
        if self.idx is not self.idx_plain and not self.s.item(BE) > 0.0:
            # a band the search took on a frame it then could not place is not followed: its states were never set,
            # and solved among the active ones their zero prior would make this update singular
            self._band_off()
        grating_z = reference_mm if self.grating == "fuse" and math.isfinite(reference_mm) else math.nan
        self._checked = reference_mm if self.grating == "check" else math.nan
        s_prior, P_prior = self.s, self.P  # read, never written (once predicted), until the posterior replaces them
        s, A, stats = self._solve(y, mask, s_prior, P_prior, grating_z, out=self._answer, predict=predict,
                                  light_dt=dt)
        if self.grating == "check" and math.isfinite(reference_mm) and \
                abs(s_prior.item(X) - reference_mm) > 0.25 * self.model.period_mm:
            self._acquire(y, mask, t, reference_mm)  # the image's period lost: start again at the grating
            s, A, stats = self._solve(y, mask, s_prior, P_prior, grating_z, out=self._answer, light_dt=dt)
        if stats[S_POSTERIOR] > 0 and self.params.item(U_LIGHT) > 0.0:
            # what the frame read of the light, weighed under both its modes (light_modes.py) in the update's call
            self.light.probability = stats[S_LIGHT]
        test = self._test(stats)
        # (read and checked, the grating's test is the position's: what a frame leaves at its samples speaks of them
        # wherever the state's memory carries its position's variance, as the frame's flags do)
        located = self._checked == self._checked
        landed = False
        if test > 1.0 and (stats[S_REJECTED] > 0 or stats[S_WEIGHED] > 0) and dt is not None and \
                not s_prior.item(BE) > 0.0 and \
                (located or stats[kernel.S_POSTERIOR] > 0 and self._anchored(self._P_next, stats)) and \
                self._marks_only(y, mask, s, True) and self._landed(y, mask, s, s_prior, P_prior, grating_z) > 0:
            # A frame that fails with samples its robust weights set aside has marks on them first: something
            # landed on a few samples (a speck on the window or the print) is what they show before any change of
            # the whole image is (a jump of the light, the lens or the mount would otherwise take a speck with the
            # samples it cannot explain set aside: a magnification jump of 0.5 % seen taking one). They wait outside
            # the position until the motion resolves them (sensor_map.py), and the frame is solved again without
            # them; what fails then is searched as before.
            y, mask = self._through_maps(y_raw, raw_mask, True)
            s, A, stats = self._solve(y, mask, s_prior, P_prior, grating_z, out=self._answer)
            test = self._test(stats)
            landed = True
        main = stats  # the frame's own update (its posterior in _P_next)
        if test > 1.0:
            test, mode, s, A, stats, solved, reason_jump = self._search(y, mask, s, A, stats, test, s_prior, P_prior,
                                                                         grating_z)
        else:
            mode, solved, reason_jump = "", self.idx, None
            self._unexplained = []
            self._placed_again = False
            self._band_missed = 0
        if not landed and (test > 1.0 or stats[S_REJECTED] > 0 or stats[S_WEIGHED] > 0) and not mode and \
                dt is not None and (located or main[S_POSTERIOR] > 0 and self._anchored(self._P_next, main)) and \
                self._landed(y, mask, s, s_prior, P_prior, grating_z) > 0:
            # Something landed on samples no jump of the state explains (a speck on the window, a veil): they wait
            # outside the position until the motion resolves them (sensor_map.py), and the frame is solved again
            # without them, so what they showed moves no state.
            y, mask = self._through_maps(y_raw, raw_mask, True)
            s, A, stats = self._solve(y, mask, s_prior, P_prior, grating_z, out=self._answer)
            test, mode, s, A, stats, solved, reason_jump = self._search(y, mask, s, A, stats, self._test(stats),
                                                                         s_prior, P_prior, grating_z)
        placed = stats[kernel.S_CONVERGED] > 0 or stats[kernel.S_ITER] > 0
        used, rejected = stats[kernel.S_USED], stats[kernel.S_REJECTED]
        if used + rejected <= 0 or rejected > self.settings.max_rejected * (used + rejected) or \
                not math.isfinite(s.item(X)):
            placed = False
        if not placed:
            self.failed += 1
            return self._unplaced(t, stats, test, "too many samples set aside" if rejected else "not converged")
        self.failed = 0
        if self._folded:
            x = s.item(X)
            self._reach = [min(self._reach[0], x), max(self._reach[1], x)]
            self._print_at_place(x)
        # Read and checked, a grating that finds the carriage where the frame's account does not place the image is a
        # measurement the account failed: the frame is reported as its image placed it (flagged by that test), and
        # the recursion carries on from the account the grating agrees with (_carried), not from one it refuted.
        # (the main update's posterior is made already: its position's variance is read, not inverted again)
        made = self._P_next.item(X, X) if A is self._answer[1] and stats[kernel.S_POSTERIOR] > 0 else None
        refuted = located and self._with_grating(test, s, A, stats, made) > 1.0
        if refuted:
            if len(self._refutations) < self._step_frames:  # (a knock shows its whole step from its first frame)
                var = (made if made is not None else self.P.item(X, X)) + self.grating_var
                self._refutations.append((s.item(X) - reference_mm, var))
                # (a knock moves the whole image: each frame's own account still explains every sample)
                self._spoiled = self._spoiled or bool(mode) or test > 1.0 or stats[S_REJECTED] > 0 or \
                    stats[S_WEIGHED] > 0
        else:
            self._refutations.clear()
            # (refutations that follow a frame off its test, or a jump of another family, may be what that frame or
            # jump put the account off by: no step of the camera's place)
            self._spoiled = bool(mode) or test > 1.0
        knocked = self._steady_step() if refuted else None
        self._pinned = None
        # (the lens's lever learned only where the image explains itself and the grating alone refutes it: a slide;
        # a frame with samples set aside or off its test may be stretched by what sits on them)
        lens = refuted and not mode and test <= 1.0 and stats[S_REJECTED] <= 0 and stats[S_WEIGHED] <= 0 and \
            not self.sensor.touched.any() and not self.print_map.touched.any()
        # (an account that needed a jump to explain its frame, or explains it not at all, and that the grating
        # refutes has no claim on the frames after it: they go on from the grating's account, the one with no state
        # jumped where none pinned to the grating explains the frame; a frame acquired is a start, which the next
        # frames judge)
        carried = self._carried(y, mask, s_prior, P_prior, lens, (bool(mode) or test > 1.0) and not acquiring) \
            if refuted and knocked is None else None
        if refuted and self._pinned is not None:
            self._land_refuted(y, mask, self._pinned)
        if not refuted:
            self._refuted_missed = 0
        if s is self._answer[0]:  # the main update's arrays: the state's becomes the next answer's
            self._answer = (self.s, A, self._answer[2])
        self.s = s
        if self._weighing:  # the frame's marginal likelihood: the cost at the update and the Occam factor
            # (the samples' misfit counted at what calibration measured of a frame's error beside their noise: a model
            # erring a few floors along the stroke leaves misfits that a shape freed would take up on any run)
            sign, occam = np.linalg.slogdet(P_prior[np.ix_(solved, solved)] @ A)
            share = self._model_share(s.item(X))
            self.evidence = -0.5 * (stats[kernel.S_COST] / (1.0 + share) + occam) if sign > 0 else math.nan
        if A is self._answer[1] and stats[kernel.S_POSTERIOR] > 0:  # the main update's: it made the posterior
            self.P, self._P_next = self._P_next, self.P
        else:
            # the posterior over the states solved, the prior's elsewhere (the jitter's conditioned on them)
            kernel.embed(self.P, A, solved, self._sigma, stats.gains)
        if self.grating == "none":  # (_lens's own test, without the call on every other frame)
            self._lens(s_prior, P_prior)
        if self.s.item(BE) > 0.0:
            self._band_failed = self._band_failed + 1 if test > 1.0 else 0
            if self._band_failed >= FAILED_TO_REACQUIRE or self._band_gone():
                self._band_off()
        step = knocked
        if knocked is not None:
            self._mounted(knocked)
            self._refutations.clear()
            mode = reason_jump = "geometry"
        elif self.mount is not None and any(family in MOUNT_BLIND for family in mode.split("+")):
            # a jump of the light or the lens moved the position with it (over less than a period they trade with a
            # shift): what the frames before it placed is no line to judge a step of the mount against
            self.mount.reset()
        # (frames that set samples aside, or weighed them down, place the image no better than what they set
        # aside moved it: a glint's frame is several floors off and would read as a step)
        elif self.mount is not None and test <= 1.0 and stats[kernel.S_XINFO] > 0 and \
                stats[S_REJECTED] <= 0 and stats[S_WEIGHED] <= 0:
            # (the frame's noise and the model's own error there, which its calibration measured against the grating:
            # a model that places a frame several floors off scatters its positions by as much from frame to frame)
            x = self.s.item(X)
            level = self.params.item(kernel.U_LEVEL)
            step = self.mount.add(t, x, self._frame_variance(x, stats[kernel.S_XINFO], level))
            if step is not None:
                self._mounted(step)
                mode = reason_jump = "geometry"
        if mode or test > 1.0:
            self._changed = True
        estimate = self._estimate(t, stats, test, mode, reason_jump, reference_mm)
        self._last_mode = mode
        if step is not None:
            where = (f"the grating's carriage over the last {self._step_frames} frames and held it"
                     if knocked is not None else
                     f"the carriage between the last two frames, beyond the {step.allowance_mm * 1e3:.1f} µm the "
                     f"stage's acceleration allows")
            estimate = estimate._replace(
                stale=True, stale_reason="geometry",
                message=f"the image stepped {step.step_mm * 1e3:+.1f} ± {step.sigma_mm * 1e3:.1f} µm against "
                        f"{where}: the camera moved on its mount")
        # (a frame flagged only for the window's drift against the grating, less than a bound a frame, places what
        # it shows of the print by less than a bound off: what the maps learn from it stands)
        vouched = not estimate.stale or self._drift_only
        if self.sensor.active or self.print_map.active:
            # where a frame sees a place of the print says how far the print carried it only where the one test
            # vouches for the frame's position (a flagged frame may be placed a pixel off: a jump taken, the
            # grating disagreeing); the maps learn from what it leaves at the samples wherever its position is
            # its own (a change being learned is flagged until it is)
            anchored = self._anchored(self.P, stats)
            self._learn(y_raw, raw_mask, y, mask, t, anchored, anchored and vouched)
        if self.survey_sigma > 0.0 and vouched and self._anchored(self.P, stats):
            self._survey(y, mask, t)
        if self.print_origin is not None and self._origin_periods is None and vouched and \
                self._anchored(self.P, stats):
            self._find_origin(y_raw, raw_mask)
        if carried is not None:  # (the maps learn from the frame as its image placed it, as it is reported)
            self.s, A, idx, self.P, figures = carried
            kernel.embed(self.P, A, idx, self._sigma, figures.gains)
            if idx is self.idx_band and self.idx is not self.idx_band:
                self._band_on()
        return estimate

    def commanded(self, start: float, end: float, acceleration: float | None = None) -> None:
        """A phase of acceleration the stage's owner commanded (``start``, ``end`` s in the frames' clock, |a|
        mm/s², None: the stage's most), as it issues it (the same ``start`` again: that phase's end now known):
        without the grating, the mount's test allows that there and, between the phases it was given, only what
        the stage does beyond its commands (mount.py). Read or fused, the grating says."""
        if self.mount is not None:
            self.mount.command(start, end, acceleration)  # (the window's oldest frame: what it drops)
        else:
            self.commands.command(start, end, acceleration, -math.inf if self.t_last is None else self.t_last)
        if self._contest is not None:  # (the rivals of the first frames hear the stage's commands too)
            for rival in self._contest.rivals:
                rival.estimator.commanded(start, end, acceleration)

    def _carried(self, y: np.ndarray, mask: np.ndarray, s_prior: np.ndarray, P_prior: np.ndarray,
                 lens: bool = False, doubted: bool = False
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, _Figures] | None:
        """The frame's account with the grating it checks as a second measurement of the carriage, for the
        recursion to carry where the image's own account and the grating disagree: (state, posterior information,
        the states solved, the prior's covariance to embed it in, the solve's figures). Solved with the grating,
        and with the jump of each family its score test then points to (the frame's innovation seen with the carriage
        pinned: a vignetting change or a veil forming reads as the light's shape there, not as a shift), or with a
        band entering, the account that explains the gray values best is kept. Where none explains them within
        their test, the frame's own account stands, as it did before the grating refuted it (None), unless it is
        ``doubted``: it needed a jump to explain the frame, or does not explain it either (once the recursion has
        started: a first frame's account, acquired from the image alone, is a start; its pinned account, fitted to
        whatever the image then holds, dust on the window not yet learned, would carry that instead). The
        recursion then goes on from the account with the carriage pinned and no state jumped. A model that no longer
        fits the print (its tone curve changed, a sensor's gamma, a lens refocused) fits it best somewhere the grating
        refutes, a light's jump taking it there on the second frame (the paper rig's print tone: 387 µm off, carried
        on for a hundred frames while the focus and the light's shape bent to keep it); the grating's account, even
        failing, is where the carriage is. One that explains its frame without a jump still stands against the grating
        (a knock: the image moved against the carriage, and the grating refutes it by one offset from then on)."""
        self._pinned = None
        if (self.idx is self.idx_band) != (s_prior.item(BE) > 0.0):
            return None  # (a band entered or left on this frame: its account stands)
        reading = self._checked
        P_keep = P_prior.copy()
        s_f, A_f, stats_f = self._solve(y, mask, s_prior, P_keep, reading)
        if not math.isfinite(s_f[X]):
            return None
        self._pinned = s_f  # (the carriage pinned, no state jumped: what _land_refuted lands from)
        best = plain = (self._chi2(stats_f), s_f, A_f, stats_f, self.idx, "")
        ranked = self._ranked(s_f, A_f, s_prior, P_keep)[:SEARCHED]
        for family in ranked:
            s_j, A_j, stats_j = self._solve(y, mask, s_prior, self._jumped(P_keep, family), reading)
            chi2 = self._chi2(stats_j)
            if math.isfinite(s_j[X]) and chi2 < best[0]:
                best = (chi2, s_j, A_j, stats_j, self.idx, family)
        if lens and self.idx is self.idx_plain and self.idx_carried is not self.idx_plain:
            # the lens's lever solved too, with the jump that explained most: a state more, taken where it explains
            # more by its quantile (a light's shape changing stretches the image as the lens does over less than a
            # period, and its jump explains it without a lever that would stay)
            P_lens = self._jumped(P_keep, best[5]) if best[5] else P_keep
            s_l, A_l, stats_l = self._solve(y, mask, s_prior, P_lens, reading, self.idx_carried)
            if math.isfinite(s_l[X]) and self._chi2(stats_l) + self._lever_margin < best[0]:
                best = (self._chi2(stats_l), s_l, A_l, stats_l, self.idx_carried, best[5])
        missed = self._refuted_missed
        self._refuted_missed = missed + 1
        if ranked and s_prior.item(BE) <= 0.0 and missed & (missed - 1) == 0:
            # (as in the frame's own search: a band entering is taken over a jump only where it explains more by its
            # extra states' quantile, and while a refutation it did not explain persists, searched again at doubling
            # intervals: a knock refutes every later frame's account, and no band is what it shows)
            banded = self._banded(y, mask, s_f, s_prior, P_keep, reading)
            if banded is not None and banded[0] <= 1.0 and self._chi2(banded[3]) + self._band_margin < best[0]:
                self._refuted_missed = 0
                return banded[1], banded[2], self.idx_band, P_keep, banded[3]
        _, s_f, A_f, stats_f, idx, _ = best
        if self._test(stats_f) > 1.0:
            if not doubted:
                return None  # (no account the grating agrees with explains the frame either: the frame's own stands)
            # (the grating's plain account, no state jumped: a jump that explains the frame no better than failing is
            # not taken as one; a magnification's jump taken there for a shadow's edge stayed in every later frame)
            _, s_f, A_f, stats_f, idx, _ = plain
        return s_f, A_f, idx, P_keep, stats_f

    def _mounted(self, step: Step) -> None:
        """The camera's place takes the step the mount made (mount.py): the carriage is where the image was less
        the step, and both carry the step's variance (its fit's and what the stage may have done within its
        allowance, uniform over ±allowance) in the one direction the frames cannot see, place against carriage."""
        d = step.step_mm
        var = step.sigma_mm ** 2 + step.allowance_mm ** 2 / 3.0
        s, P = self.s, self.P
        s[X] -= d
        s[C] += d
        P[X, X] += var
        P[C, C] += var
        P[X, C] -= var
        P[C, X] -= var
        self._sigma[X], self._sigma[C] = math.sqrt(P[X, X]), math.sqrt(P[C, C])

    # ------------------------------------------------------------------ parts
    def _search(self, y: np.ndarray, mask: np.ndarray, s: np.ndarray, A: np.ndarray, stats: list, test: float,
                s_prior: np.ndarray, P_prior: np.ndarray, grating_z: float) -> tuple:
        """The frame's update decided: as it is where its test passes, else with the jump that explains it, else
        at the weight its χ² says its samples are worth. Returns (test, mode, state, information, figures, the
        states solved, the family whose jump explained most where none did)."""
        mode, solved = "", self.idx
        if test > 1.0:
            best = None
            if s_prior.item(BE) > 0.0:
                # A band followed jumps in its shape first (a band half in view has shown one edge only; the
                # field's tilt and a shift would otherwise take what its other edge shows as it enters).
                s_j, A_j, stats_j = self._solve(y, mask, s_prior, self._band_widened(P_prior, s_prior), grating_z)
                test_j = self._test(stats_j)
                if test_j <= 1.0:
                    self._unexplained = []
                    return test_j, "band", s_j, A_j, stats_j, self.idx, None
            ranked = self._ranked(s, A, s_prior, P_prior)[:SEARCHED]
            if ranked == self._unexplained:
                # A jump is a step at one frame. The families whose jumps did not explain the last frame, pointed
                # at again in the same order, are the same unexplained change persisting (a veil, a shadow on its
                # way), not a new step: their jumps are not solved again.
                ranked = []
            # (each jump's test and, where the grating is read and checked, the grating's with it: a jump both
            # find explains the frame before one the grating contradicts; where none does, the gray values decide)
            tried = []
            for family in ranked:
                widened = self._jumped(P_prior, family)
                s_j, A_j, stats_j = self._solve(y, mask, s_prior, widened, grating_z)
                test_j = self._test(stats_j)
                tried.append((self._with_grating(test_j, s_j, A_j, stats_j), test_j, family, s_j, A_j, stats_j))
            if len(tried) > 1 and min(candidate[0] for candidate in tried) > 1.0 and \
                    REASON[ranked[0]] == REASON[ranked[1]] and self._band_missed == 0:
                # One change may move two families of one cause at once (a vignetting change or a lamp moved: the
                # light's level and its shape; a knock: the camera's place and the stage's velocity seen): where
                # neither jump alone explains the frame, the two jump together. A step, it comes on a frame after
                # one the model described. (Of two causes, or on a change under way, their joint freedom would
                # over less than a period explain a change neither made: a veil forming taken by the field.)
                family = "+".join(ranked)
                s_j, A_j, stats_j = self._solve(y, mask, s_prior, self._jumped(P_prior, family), grating_z)
                test_j = self._test(stats_j)
                both_j = self._with_grating(test_j, s_j, A_j, stats_j)
                if both_j <= 1.0 or self._checked != self._checked:
                    # (read and checked, the grating must find the carriage where the two place the image)
                    tried.append((both_j, test_j, family, s_j, A_j, stats_j))
            if tried:
                both = min(tried, key=lambda candidate: candidate[0])
                best = both[1:] if both[0] <= 1.0 else min(tried, key=lambda candidate: candidate[1])[1:]
            missed = self._band_missed
            if s_prior.item(BE) <= 0.0 and missed & (missed - 1) == 0:
                # A change may be a band of shadow or veil entering the field (a shape of the light no low-order
                # field describes, which over less than a period the field's tilt and a shift would take between
                # them): searched on a frame that fails while none is followed, and taken over a jump that
                # explains the frame too only where it explains it better by more than the band's extra states'
                # χ² quantile at the false-alarm rate. While a change the search did not take persists, it is
                # searched again at doubling intervals (a band entering shows more of itself frame by frame; a
                # smudge on the print never becomes one).
                banded = self._banded(y, mask, s, s_prior, P_prior, grating_z)
                if banded is not None and banded[0] <= 1.0 and (
                        best is None or best[0] > 1.0 or
                        self._chi2(banded[3]) + self._band_margin < self._chi2(best[4])):
                    self._band_on()
                    self._unexplained = []
                    self._band_missed = 0
                    return banded[0], "band", banded[1], banded[2], banded[3], self.idx, None
            if s_prior.item(BE) <= 0.0:
                self._band_missed = missed + 1
            if best is not None and best[0] <= 1.0:
                test, mode, s, A, stats = best[0], best[1], best[2], best[3], best[4]
                reason_jump = None
                self._unexplained = []
            else:
                if ranked:
                    self._unexplained = ranked
                reason_jump = best[1] if best is not None and best[0] < test else None
                # No mode explains the frame: its noise is evidently beyond the noise model's. Its samples
                # count for as much as its χ² says they are worth (the measurement's covariance scaled by the
                # innovation's excess), so the frame moves the state little and its bound widens. It updates
                # the motion and the image's appearance (the light, its shape, the focus), which is what such
                # a frame speaks of: held instead, a shape a wrong jump left would stay for every later frame,
                # each failing in turn. The geometry (the camera's place, the lens, the grating's latch),
                # learned over spans of the grating, is not taught by a frame the model does not explain.
                inflation = self._excess(stats)
                solved = self.idx_appearance  # (solved again from the frame's own solution and weights)
                s, A, stats = self._solve(y, mask / inflation, s_prior, P_prior, grating_z,
                                          solved, start=s)
        else:
            reason_jump = None
            self._unexplained = []
        return test, mode, s, A, stats, solved, reason_jump

    def _banded(self, y: np.ndarray, mask: np.ndarray, s: np.ndarray, s_prior: np.ndarray,
                P_prior: np.ndarray, grating_z: float) -> tuple | None:
        """A band entering, searched among the shapes of ``_bands`` on what the update ``s`` left (each shape's
        depth the weighted least-squares one of the residual, the shape whose depth explains most taken), then
        solved from there with its states free about it (their entering priors): (test, state, information,
        figures), or None where no shape explains anything."""
        if self._marks_only(y, mask, s):
            return None
        residual, values = self.scratch[5], self.scratch[0]
        weight = mask / self._noise_var
        seen = -(s[G] + s[A1] * self.b1 + s[A2] * self.b2) * values  # the gray a band of depth 1 takes
        shapes = self._bands
        # each shape's depth and haze by weighted least squares of the residual, their entering priors about none
        # (two unknowns, five sums a shape; the priors keep a band whose edge alone is in view from trading a deep
        # shadow for a bright haze)
        band, square = shapes.band, shapes.square
        a11 = square @ (weight * seen * seen) + 1.0 / self.settings.band_prior_depth ** 2
        a12 = square @ (weight * seen)
        a22 = square @ weight + 1.0 / self.settings.band_prior_haze ** 2
        b1, b2 = band @ (weight * residual * seen), band @ (weight * residual)
        det = a11 * a22 - a12 * a12
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(det > 0.0, (b1 * a22 - b2 * a12) / det, 0.0)
            haze = np.where(det > 0.0, (b2 * a11 - b1 * a12) / det, 0.0)
            gain = np.where((det > 0.0) & (np.abs(depth) < 1.0), depth * b1 + haze * b2, 0.0)
        k = int(np.argmax(gain))
        # (the shape that explains most is solved whatever share of the frame's excess it explains at ``s``: where
        # a band entered on the frames before, ``s`` is an update the band pulled, whose shift and light took part
        # of what the band shows; solved from the prior with the band, a veil forming over a strip was found a
        # second later at a tenth of that share, after the frames it pulled had run the position 200 µm off)
        if not gain[k] > 0.0:
            return None
        start = s_prior.copy()
        start[BD], start[BL], start[BR], start[BW], start[BE], start[BH] = (
            depth[k], shapes.left[k], shapes.right[k], 0.0, shapes.edge[k], haze[k])
        # A band entering shows on its first frames as a change of the light or its shape, which a jump of those may
        # explain on that frame by fewer states; searched on the frame after such a jump, the band is solved with the
        # light as free as that jump left it, so that it takes back what the jump took (held at the jump's posterior,
        # a shadow's first pass was left to the jump's light and the position: 2.1 noise floors against 1.45)
        jumped = "+".join(family for family in self._last_mode.split("+") if family in LIGHT_JUMPS)
        widened = self._jumped(P_prior, jumped) if jumped else P_prior.copy()
        for state in BAND:
            widened[state, :] = 0.0
            widened[:, state] = 0.0
        widened = self._band_widened(widened, start)
        s_b, A_b, stats_b = self._solve(y, mask, start, widened, grating_z, self.idx_band)
        if not math.isfinite(s_b[X]) or self._band_unlike(s_b):
            return None
        return self._test(stats_b), s_b, A_b, stats_b

    def _marks_only(self, y: np.ndarray, mask: np.ndarray, s: np.ndarray, inside: bool = False) -> bool:
        """Whether what the frame leaves at ``s`` (its residuals left in ``scratch[5]``) is marks only: a shape of
        the light leaves residuals of one sign over a run of samples as wide as the narrowest band, each beyond its
        noise (by chance: 0.16 to the 17th power on a hundred samples); what a frame leaves in shorter runs is
        marks (specks on the window or the print: the maps' and the robust weights'). ``inside``: and none of them
        at either end of a row (EDGE_RUN samples of one sign beyond their noise there: a band's edge may be
        entering, which its first frames show as a short run at the field's end)."""
        kernel.residuals(s, y, mask, self.rho, self.pixels, self.params, self.model_args, self.scratch,
                         self._noise_var)
        scaled = self.scratch[5] * np.sqrt(mask / self._noise_var / self._level(s.item(X)))
        width = self.model.n_pixels
        runs = max(kernel.longest_run(scaled, width, 1.0), kernel.longest_run(scaled, width, -1.0))
        if runs >= width / 6.0:
            return False
        if inside:
            rows = scaled.reshape(-1, width)
            for end in (rows[:, :EDGE_RUN], rows[:, -EDGE_RUN:]):
                if ((end > 1.0).all(axis=1) | (end < -1.0).all(axis=1)).any():
                    return False
        return True

    def _band_widened(self, P: np.ndarray, s: np.ndarray) -> np.ndarray:
        """``P`` with the band's entering priors added to its states (a copy)."""
        settings = self.settings
        widened = P.copy()
        for state, sigma in zip(BAND, (settings.band_prior_depth, settings.band_prior_edge, settings.band_prior_edge,
                                       settings.band_prior_speed, settings.band_prior_soft, settings.band_prior_haze)):
            widened[state, state] += sigma * sigma
        return widened

    def _band_on(self) -> None:
        """A band followed from this frame: its states among the active ones."""
        self._band_entered = self._image(self.s)[0]
        self._band_edges, self._band_print = None, False
        self.rates2[BW] = self.params[kernel.U_RATES + BW] = self.settings.band_acceleration ** 2
        self.idx, self._layout = self.idx_band, self._layout_band
        self._answer = (self._answer[0], np.empty((self.idx.size, self.idx.size)), self._answer[2])

    def _band_off(self) -> None:
        """No band in view: its states held at zero, out of the active ones."""
        self._band_failed = 0
        for state in BAND:
            self.s[state] = 0.0
            self.P[state, :] = 0.0
            self.P[:, state] = 0.0
        if self.idx is not self.idx_plain:
            self.idx, self._layout = self.idx_plain, self._layout_plain
            self._answer = (self._answer[0], np.empty((self.idx.size, self.idx.size)), self._answer[2])

    def _band_on_print(self) -> None:
        """A band the print carries is the print's (a smudge, a stain): told by the motion, as a mark on the print is
        (sensor_map.py), once the print has carried the image across BAND_HELD_TRAVEL of the band's first penumbras
        and an edge in view moved with it (by the image's travel against it, within half of that), and from then on
        its speed across the field is the print's under the camera, the stage's velocity against it, before every
        frame (the band's edges then move with the position and no longer trade with it over less than a period;
        followed at a swinging cable's acceleration, a smudge's band let the position run 10-40 µm off under it)."""
        s = self.s.tolist()
        if self._band_edges is None:
            self._band_edges = (s[BL], s[BR], s[BE])
            return
        if not self._band_print:
            travel = s[X] + s[C] + s[L] * s[M] - self._band_entered
            lo, hi = self._bands.lo, self._bands.hi
            moved = [s[edge] - was for edge, was in zip((BL, BR), self._band_edges[:2]) if lo <= s[edge] <= hi]
            self._band_print = bool(moved) and abs(travel) > BAND_HELD_TRAVEL * self._band_edges[2] and \
                min(abs(m + travel) for m in moved) < 0.5 * abs(travel)
        if self._band_print:
            P = self.P
            self.s[BW] = -self.s[V]
            P[BW, :] = -P[V, :]
            P[:, BW] = -P[:, V]
            P[BW, BW] = P[V, V] + BAND_SLIP * BAND_SLIP
            self.rates2[BW] = self.params[kernel.U_RATES + BW] = 0.0

    def _band_unlike(self, s: np.ndarray) -> bool:
        """Whether a band's shape is no band's: narrower than a sixth of the field (a speck, a scratch: the maps'
        and the robust weights' marks, not a light's shape; its penumbra is solved no sharper than BAND_SHARPEST
        of the field, kernel.U_BAND_SHARPEST), or scattering more than BAND_HAZIEST of the light it takes (a depth
        and a haze that cancel change the print's contrast, not its light: marks on it)."""
        field = self._bands.hi - self._bands.lo
        return s.item(BR) - s.item(BL) < field / 6.0 or \
            abs(s.item(BH)) > BAND_HAZIEST * abs(s.item(BD)) * max(abs(self.mean_gray), 1.0)

    def _band_held(self, s: list, sigma: list) -> bool:
        """Whether the band followed has held its place on the pixels (its speed within its test of nought) while
        the print carried the image across BAND_HELD_TRAVEL of its penumbras since it entered: a veil on the window,
        a shadow that stays. A position paired wrongly with its edges would have moved them with the print (the
        print's pattern is what places the image): held, they are the camera's, and the motion has told the two
        apart, as it tells a mark on the window from one on the print (sensor_map.py)."""
        return abs(s[BW]) <= self.z_two * sigma[BW] and \
            abs(s[X] + s[C] + s[L] * s[M] - self._band_entered) > BAND_HELD_TRAVEL * s[BE]

    def _band_gone(self) -> bool:
        """Whether the band followed has left the field or closed: the light it takes anywhere in view (its
        largest at the field's ends or its middle) below half a sample's read noise."""
        s = self.s
        depth, left, right, edge = s.item(BD), s.item(BL), s.item(BR), s.item(BE)
        if self._band_unlike(s):
            return True
        lo, hi = self._bands.lo, self._bands.hi
        scale = 1.0 / (math.sqrt(2.0) * edge)
        centre = min(max(0.5 * (left + right), lo), hi)
        mean, haze = max(abs(self.mean_gray), 1.0), s.item(BH)
        taken = max(abs(depth * mean - haze) * 0.5 * (math.erf((u - left) * scale) - math.erf((u - right) * scale))
                    for u in (lo, hi, centre))
        return taken < 0.5 * math.sqrt(self.noise[0])

    def _landed(self, y: np.ndarray, mask: np.ndarray, s: np.ndarray, s_prior: np.ndarray, P_prior: np.ndarray,
                grating_z: float) -> int:
        """Samples something landed on, tested at the frame's update ``s`` (sensor_map.land). Where more fail
        than the map may hold, the update itself may be what the marks pulled (specks on the window from the
        first frame leave no clean state to test against: every sample then fails, the robust weights' scale
        with them): the frame is placed again by the samples that agree (``_agreed``), solved from those with
        the light free, and tested at that solution. A state truly misplaced (its light, its position) is
        placed right by its own samples, and few fail."""
        fresh = self._land_at(y, mask, s)
        if fresh >= 0 or self.sensor.most <= 0.0:  # (a map that may hold nothing: no placing again for it)
            return max(fresh, 0)
        if self._placed_again:
            # Placed again in vain on an earlier frame of this episode (frames failing since): what fails is the
            # state's or a mark too wide for the map (a veil, a smudge), not marks the update was pulled by. Not
            # placed again until a frame passes its test.
            return 0
        self._placed_again = True
        agreed = self._agreed(y, mask, s)
        if agreed is None:
            return 0
        x_mm, kept = agreed
        start = s.copy()
        start[X] = x_mm
        self.rho[:] = 1.0
        s, _, stats = self._solve(y, mask * kept, s_prior, self._jumped(P_prior, "light"), grating_z, start=start)
        if not math.isfinite(s[X]) or stats[kernel.S_USED] <= 0:
            return 0
        fresh = max(self._land_at(y, mask, s), 0)
        self._placed_again = fresh == 0
        return fresh

    def _agreed(self, y: np.ndarray, mask: np.ndarray, s: np.ndarray) -> tuple[float, np.ndarray] | None:
        """The position within a quarter period of ``s`` that most samples agree with, and those samples: on a
        grid of ``AGREED_GRID`` positions, then as many within a step of the best (a strip's averaged rows make
        the agreement narrower than a step), the model's values with the light the agreeing samples share
        (kernel.agreement: each sample's gain against the model, the shortest span holding the share the map
        would leave, then refitted ``AGREED_ROUNDS`` times to the samples within the per-sample test; each
        position's cost its samples' χ² with every sample's capped at the test: a mark costs what it costs,
        however deep). None: no position leaves enough samples to solve with."""
        weight = mask / self._noise_var
        half = int(math.ceil((1.0 - self.sensor.most) * np.count_nonzero(weight > 0.0)))
        if half <= self.idx.size:
            return None
        cap = self.sensor.z2 * self.sensor.level
        cost, gain, offset = np.empty(AGREED_GRID), np.zeros(AGREED_GRID), np.zeros(AGREED_GRID)
        step = 0.5 * self.model.period_mm / (AGREED_GRID - 1)
        centre = float(s[X])
        for reach in (0.25 * self.model.period_mm, step):
            grid = centre + np.linspace(-reach, reach, AGREED_GRID)
            values, _ = self.evaluator.evaluate(grid)
            kernel.agreement(y, weight, values, half, float(s[OFS]), cap, AGREED_ROUNDS, cost, gain, offset)
            best = int(np.argmin(cost))
            if not math.isfinite(cost[best]):
                return None
            centre = float(grid[best])
        chi2 = (y - gain[best] * values[best] - offset[best]) ** 2 * weight
        kept = (chi2 < cap) & (weight > 0.0)
        if kept.sum() <= self.idx.size:
            return None
        return centre, kept.astype(np.float64)

    def _land_at(self, y: np.ndarray, mask: np.ndarray, s: np.ndarray, hold: float | None = None) -> int:
        """sensor_map.land with the frame's residuals at ``s`` (left in ``scratch[5]``, their weights in
        ``scratch[4]``)."""
        kernel.residuals(s, y, mask, self.rho, self.pixels, self.params, self.model_args, self.scratch,
                         self._noise_var)
        weight = self.scratch[4]
        np.divide(mask, self._noise_var, out=weight)
        fresh = self.sensor.land(self.scratch[5], weight, hold)
        if fresh > 0:  # each a candidate on the print too, where the image at ``s`` places it (print_map.py)
            xi, stretch, _ = self._image(s)
            self.print_map.land(self.sensor.core, self.t_last or 0.0, xi, stretch)
        return fresh

    def _through_maps(self, y_raw: np.ndarray, raw_mask: np.ndarray, located: bool) -> tuple[np.ndarray, np.ndarray]:
        """The frame through the sensor's map and, where the image's place is known (``located``: the state
        predicted to the frame), the print's map at that place."""
        y, mask = self.sensor.seen(y_raw, raw_mask) if self.sensor.active else (y_raw, raw_mask)
        self._printed = self.print_map.active and located
        if self._printed:
            y, mask = self.print_map.seen(y, mask, *self._image(self.s, self.P))
        return y, mask

    @staticmethod
    def _image(s: np.ndarray, P: np.ndarray | None = None) -> tuple[float, float, float]:
        """The image's position ξ = x + c + L·m (what the print under the camera is placed by), the stretch, and
        ξ's variance under ``P`` (0 without)."""
        x, c, lever, stretch = s.item(X), s.item(C), s.item(L), s.item(M)
        if P is None:
            return x + c + lever * stretch, stretch, 0.0
        # gᵀ P g with g = (1, 1, m, L) over (x, c, L, m), written out (a frame calls this several times)
        pxx, pcc, pll, pmm = P.item(X, X), P.item(C, C), P.item(L, L), P.item(M, M)
        pxc, pxl, pxm = P.item(X, C), P.item(X, L), P.item(X, M)
        pcl, pcm, plm = P.item(C, L), P.item(C, M), P.item(L, M)
        var = (pxx + pcc + stretch * stretch * pll + lever * lever * pmm
               + 2.0 * (pxc + stretch * (pxl + pcl) + lever * (pxm + pcm) + stretch * lever * plm))
        return x + c + lever * stretch, stretch, max(var, 0.0)

    def _learn(self, y_raw: np.ndarray, raw_mask: np.ndarray, y: np.ndarray, mask: np.ndarray, t: float,
               teach: bool, vouched: bool) -> None:
        """What the placed frame left at each sample something landed on, into the maps: the print's from the
        sample with the sensor's side divided out where the sensor's map uses it there, the sensor's against the
        model's value with the print's change at that place. Each candidate explains the raw sample alone until
        the motion has decided between them (print_map.py). ``mask``: the weights of ``y``, the frame as the update saw
        it."""
        kernel.residuals(self.s, y, mask, self.rho, self.pixels, self.params, self.model_args, self.scratch,
                         self._noise_var)
        expected = self._expected
        np.subtract(y, self.scratch[5], out=expected)  # the model's value at the posterior
        if self._printed:  # (a frame placed from nothing was not seen through the print's map: it teaches it nothing)
            sensor = self.sensor
            if sensor.active:
                # the sensor's side divided out where its map uses the sample; where it holds the sample as a
                # candidate, the raw sample, and what the candidate says of it is the print's rival account
                used = sensor.touched & (sensor._mask > 0.0)
                y_print = np.where(used, sensor._y, y_raw)
                held = sensor.touched & ~used
                other = np.where(held, (1.0 + sensor.f) * expected + sensor.e, expected)
                other_var = np.where(held, expected * (expected * sensor.sff + 2.0 * sensor.sfe) + sensor.see, 0.0)
            else:
                y_print, other, other_var = y_raw, expected, self._zeros
            self.print_map.learn(y_print, expected, other, other_var, self._noise_var, raw_mask, t, teach, vouched)
            expected *= 1.0 + self.print_map.fp
            rival, rival_var = self.print_map.rival, self.print_map.rival_var
        else:
            rival, rival_var = expected, self._zeros
        xi = self._image(self.s)[0]
        moved = abs(xi - self._xi_last) / self.model.pixel_pitch_mm if self._xi_last == self._xi_last else 0.0
        self._xi_last = xi
        if self.sensor.active and self.sensor.learn(y_raw, expected, rival, rival_var, self._noise_var, raw_mask,
                                                    self.dt_last, teach, moved) > 0 and self._printed:
            # A sample the sensor's side held that fails what it holds is something new there (a speck the print
            # carries past the pixel, or one settling on it at rest): a candidate on the print too, as a sample
            # neither map held is (_land_at), or the sensor's pair, with the print's side as calibrated there,
            # would beat it on the print's own mark.
            xi, stretch, _ = self._image(self.s)
            self.print_map.land(self.sensor.jumped, t, xi, stretch)

    def _find_origin(self, y_raw: np.ndarray, raw_mask: np.ndarray) -> None:
        """The vouched frame (``y_raw``, its weights ``raw_mask``, seen through the sensor's map alone: the run's own
        print map may already hold the marks it weighs) weighed for calibration's marks at each place it may be
        (print_origin.py); once one is decided, the print's map restored there. (The places the bound reads the
        model's error at stay the run's travel's to narrow: told by the marks within a few frames, a run's first
        frames read there what calibration's own passing frames erred, and a run from rest erred 14 µm where those
        had 2.5.)"""
        finder, period = self.print_origin, self.model.period_mm
        x = self.s.item(X)
        candidates = [round((place - x) / period) for place in self._places(x)]
        xi, stretch, _ = self._image(self.s)
        if finder is None or not any(finder.in_view(xi, periods) for periods in candidates):
            return
        y, mask = self.sensor.seen(y_raw, raw_mask) if self.sensor.active else (y_raw, raw_mask)
        kernel.residuals(self.s, y, mask, self.rho, self.pixels, self.params, self.model_args, self.scratch,
                         self._noise_var)
        expected = np.subtract(y, self.scratch[5], out=self._expected)
        decided = finder.observe(y, expected, self._noise_var, mask, self.params.item(kernel.U_LEVEL), xi, stretch,
                                 candidates)
        if decided is not None:
            # (what the run's own map holds so far is dropped: its marks were these, or will land again)
            self.print_map.restore(finder.state, shift_mm=decided * period)
            self._origin_periods = decided

    def left(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the frame just updated left at each sample against the posterior, as the estimator sees its samples
        (through the sensor's pattern, flat_field.py): the model's value there, the residual and the sample's weight
        (its mask and robust weight over its noise's variance). New arrays."""
        y, mask = self._prepared(frame)
        kernel.residuals(self.s, y, mask, self.rho, self.pixels, self.params, self.model_args, self.scratch,
                         self._noise_var)
        residual = self.scratch[5].copy()
        return y - residual, residual, mask * self.rho / self._noise_var

    def _steady_step(self) -> Step | None:
        """The camera's step on its mount where the first ``place_step_frames`` frames of a run the grating read
        refutes disagreed with it by one offset, each pair within the false-alarm rate's two-sided σ of their
        difference, and no frame before or among them was off its test or took a jump (a knock shows its whole step
        at once and holds it; a mark the print carries, or the lens drifting, pulls each frame's account by what
        grows and changes as it moves); None otherwise. The step is their mean, its σ the mean's."""
        refutations = self._refutations
        if self._spoiled or len(refutations) < self._step_frames:
            return None
        offsets = [offset for offset, _ in refutations]
        variances = [var for _, var in refutations]
        if max(offsets) - min(offsets) > self.z_two * math.sqrt(2.0 * max(variances)):
            return None
        n = len(offsets)
        return Step(sum(offsets) / n, math.sqrt(sum(variances)) / n, 0.0, 0.0)

    def _land_refuted(self, y: np.ndarray, mask: np.ndarray, pinned: np.ndarray) -> None:
        """A frame the grating read refutes: what it leaves at each sample at ``pinned`` (the frame solved with the
        grating as a measurement, no state jumped: _carried's first account) lands in both maps, the motion to
        decide between them. A mark on the print wider than what a sample's own test catches at the image's account
        (a smudge's wings, a veil's soft edge) pulls the position and the light's shape with it over less than a
        period, so its samples pass there; with the carriage pinned they fail where the mark is. The map's hold does
        not bind here: it keeps what a misplaced state leaves out of the maps, and the grating places the carriage
        (where most samples fail at once, a knock or a lamp, nothing lands: sensor_map.land's ``most``)."""
        self._land_at(y, mask, pinned, hold=1.0)

    def _survey(self, y: np.ndarray, mask: np.ndarray, t: float) -> None:
        """Every sample of the placed frame ``y`` (as the maps show it, ``mask`` its weights: a candidate waiting
        has none) beyond ``survey_sigma`` of its variance (the noise's at the calibration's level) lands on the print
        where no node holds it yet. A frame's test lands a sample only beyond the false-alarm rate's σ across all of
        its samples, which a speck a few % deep passes by chance: on calibration's own sweep, the position pinned by
        the grating over many frames, the print's every such speck is a candidate, decided by the motion and its
        evidence as any (print_map.py), so that a run starts from it instead of learning it."""
        kernel.residuals(self.s, y, mask, self.rho, self.pixels, self.params, self.model_args, self.scratch,
                         self._noise_var)
        residual = self.scratch[5]
        beyond = mask * residual * residual > self.survey_sigma ** 2 * self.params.item(kernel.U_LEVEL) * \
            self._noise_var
        if beyond.any():
            xi, stretch, _ = self._image(self.s)
            self.print_map.land(beyond, t, xi, stretch)

    def _prepared(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The frame's gray values as the model sees them (its ``prepare``) and their mask."""
        model = self.model
        rows = 1 if frame.ndim == 1 else frame.shape[0]
        if model.n_rows == 1 and frame.ndim <= 2 and frame.shape[-1] == model.n_pixels and rows > 0:
            # the row mean prepare takes, compiled into the estimator's own array (prepare's arrays a call
            # cost a 16-row frame 5 µs)
            flags = frame.flags
            if frame.dtype not in FRAME_TYPES or not (flags.c_contiguous and flags.writeable):
                frame = np.array(frame, dtype=np.float64)
            y = self._y
            total = kernel.row_mean(frame if frame.ndim == 2 else frame.reshape(1, -1), y)
            if rows > 1 and self.sensor_range is not None:
                kernel.rows_clipped(frame, self.sensor_range[0], self.sensor_range[1], y)
            if self._seen is not None:
                np.multiply(y, self._seen, out=y)
        else:
            rows = model.rows_averaged(rows)
            y = np.ascontiguousarray(model.prepare(frame[None]).reshape(-1))
            total = float(y.sum()) if frame.dtype.kind == "f" else 0.0
        mask = self._row_masks.get(rows)
        if mask is None:  # a row mean's variance is the sample's over the rows averaged
            mask = self._row_masks[rows] = np.ascontiguousarray(self.mask * rows)
        if self.sensor_range is not None:
            lo, hi = self.sensor_range
            kernel.in_range(y, lo, hi, mask, self._masked)
            mask = self._masked
        if not math.isfinite(total):
            # a sample that is not a number (a float camera's dead pixel, a driver's gap) is set aside as a bad
            # pixel is: the frame is placed from the rest (unchecked, it made the update's matrix NaN and raised)
            bad = ~np.isfinite(y)
            y, mask = np.where(bad, 0.0, y), mask * ~bad
        if self.flat is not None:
            # (after the sensor's range, which is the camera's own: prepare may hand back the caller's frame)
            y = self.flat.apply(y, y if y is self._y else np.empty_like(y))
        return y, mask

    def _solve(self, y: np.ndarray, mask: np.ndarray, s_prior: np.ndarray, P_prior: np.ndarray,
               grating_z: float, idx: np.ndarray | None = None,
               out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
               predict: float | None = None, start: np.ndarray | None = None,
               light_dt: float | None = None) -> tuple[np.ndarray, np.ndarray, _Figures]:
        """The update over the states ``idx`` (default: every active one; the others held at the prior):
        the state, the posterior information and the figures (kernel.S_*, plain numbers). ``out``: the
        arrays to answer in (the state, the information over ``idx``, the figures), else new ones; with
        them, the posterior covariance is made into ``_P_next`` and its σ into ``_sigma`` too.
        ``predict``: the prior is first moved on by that many seconds, in place (``predict``). ``start``: the
        iterations begin there over ``idx`` (the prior's elsewhere) with the robust weights the last update left
        (the frame solved again: its own solution and weights), not at the prior's mean with full weights.
        ``light_dt``: with ``out``, the frame's reading of the light is weighed under both its modes after that
        interval (s) too, into the figures' ``S_LIGHT`` (kernel.U_LIGHT; where the light's chain weighs a frame at
        all: LightModes.weighing)."""
        idx = self.idx if idx is None else idx
        s, A, stats = out or (np.empty(N_STATE), np.empty((idx.size, idx.size)), np.empty(kernel.N_STATS))
        if start is not None:
            s[:] = s_prior
            s[idx] = start[idx]
        # (every frame solves once at least: the kernel's numbers by the names imported, no tuples made for them)
        params = self.params
        if math.isfinite(grating_z):
            grating_w = 1.0 / self.grating_var
            params[U_GRATING_Z], params[U_GRATING_W] = grating_z if grating_w else 0.0, grating_w
        else:
            params[U_GRATING_Z] = params[U_GRATING_W] = 0.0
        if predict is None:
            params[U_PREDICT] = params[U_DT] = 0.0
        else:
            params[U_PREDICT], params[U_DT] = 1.0, predict
        params[U_POSTERIOR] = 0.0 if out is None else 1.0
        weighing = None if light_dt is None or out is None else self.light.weighing(light_dt)
        if weighing is None:
            params[U_LIGHT] = 0.0
        else:
            params[U_LIGHT] = 1.0
            params[U_LIGHT + 1], params[U_LIGHT + 2], params[U_LIGHT + 3], params[U_LIGHT + 4] = weighing
        params[U_WARM] = 0.0 if start is None else 1.0
        params[U_LEVEL] = self.chi2_calibration if self.chi2_curve is None else self._level(s_prior.item(X))
        kernel.update(s, s_prior, P_prior, idx, y, mask, self.pixels, params, self.model_args, self.scratch, self.rho,
                      A, stats, self._P_next, self._sigma)
        figures = _Figures(stats[:S_GAIN].tolist())
        figures.stats = stats
        return s, A, figures

    def _level(self, x_mm: float) -> float:
        """The calibration's χ² per sample at ``x_mm``; where the frame may be at several places (_places), the
        highest of theirs (a change shows above every place the frame may be)."""
        curve = self.chi2_curve
        if curve is None:
            return self.chi2_calibration
        if self._folded:
            return self.chi2_calibration * max(curve.at(place) for place in self._places(x_mm))
        return self.chi2_calibration * curve.at(x_mm)

    def _print_at_place(self, x_mm: float) -> None:
        """Placed from the image alone, the run's coordinates are a whole number of periods off the print's (the
        acquisition's pick); until calibration's marks tell how many (_find_origin), the print's map is read at a
        place the run's travel still allows (_places): the run's own coordinates while they are one, else the
        nearest. A map read a period off sees its nodes beyond the print's grid (no mark lands there) or at another
        place's; what it held when the travel ruled its place out was placed there, and is dropped (the marks land
        again where they are). A map restored from another run keeps the shift it was saved with."""
        if self._origin_periods is not None or self.print_map.restored.any():
            return
        period = self.model.period_mm
        allowed = [round((place - x_mm) / period) for place in self._places(x_mm)]
        if round(self.print_map.shift / period) not in allowed:
            self.print_map.reread(min(allowed, key=abs) * period)

    def _places(self, x_mm: float) -> list[float]:
        """Where along the stroke a frame placed at ``x_mm`` may be: ``x_mm`` a whole number of periods on either
        way, wherever the run's placed frames moved with it stay within the stroke (``STROKE_MARGIN_MM`` beyond
        either end); ``x_mm`` itself where none does (a run that left the stroke: what it keeps there is all it
        has)."""
        period = self.model.period_mm
        lo, hi = float(self.model.stroke_range_mm[0]) - STROKE_MARGIN_MM, \
            float(self.model.stroke_range_mm[1]) + STROKE_MARGIN_MM
        low, high = min(self._reach[0], x_mm), max(self._reach[1], x_mm)
        first = math.ceil((lo - low) / period)
        last = math.floor((hi - high) / period)
        return [x_mm + k * period for k in range(first, last + 1)] or [x_mm]

    def _test(self, stats: list) -> float:
        """The innovation's χ² over its quantile at the false-alarm rate (the stream's spread counted)."""
        used = stats[kernel.S_USED]
        if used <= 0:
            return math.inf
        quantile = self._test_quantiles.get(used)
        if quantile is None:  # (a frame uses the same samples as the last one but for a few: each count once)
            quantile = self._test_quantiles[used] = _quantile(self.z_alpha, used / self.spread ** 2)
        return self._chi2(stats) / quantile

    def _with_grating(self, test: float, s: np.ndarray, A: np.ndarray, stats: list,
                      var_image: float | None = None) -> float:
        """A jump's test, with the grating's where it is read and checked (the larger of the two, each over its
        quantile at the false-alarm rate): of two jumps that explain the gray values, one that puts the image where
        the grating says the carriage is not explains less of the frame (over less than a period a gain hunting
        read as the light's shape and a shift)."""
        reading = self._checked
        if reading != reading:
            return test
        if var_image is None:  # (``var_image``: the position's posterior variance, where it is made already)
            try:
                var_image = float(np.linalg.inv(A)[0, 0])  # (the position is the first state solved)
            except np.linalg.LinAlgError:
                return test
        level = self.params.item(kernel.U_LEVEL)
        x = s.item(X)
        var_x = var_image + self._model_variance(x, var_image, stats[kernel.S_XINFO], level)
        nu = reading - x
        return max(test, nu * nu / (self.z_two2 * (var_x + self.grating_var)))

    def _chi2(self, stats: list) -> float:
        """The innovation's χ² (the stream's spread counted)."""
        # (the samples' residual is in units of their variance, the calibration's level in it: kernel.U_LEVEL)
        return (stats[kernel.S_RESIDUAL] + stats[kernel.S_PRIOR] + stats[kernel.S_GRATING]) / self.spread ** 2

    def _excess(self, stats: list) -> float:
        """The frame's residual χ² per sample over what the noise model and the calibration expect (≥ 1)."""
        used = stats[kernel.S_USED]
        if used <= 0:
            return 1.0
        return max(stats[kernel.S_RESIDUAL] / used, 1.0)

    def _ranked(self, s: np.ndarray, A: np.ndarray, s_prior: np.ndarray, P_prior: np.ndarray) -> list[str]:
        """The families that may jump, most evident first: each one's score test of the innovation (the
        Lagrange-multiplier test of a jump in its states) made from the update without a jump (kernel.scores:
        g = Λ(s⁺ − s⁻), the innovation seen in the state, against its covariance Λ − ΛP⁺Λ when nothing
        jumped): χ² with as many degrees of freedom as the family has states. A family whose statistic is
        within its quantile at the false-alarm rate cannot explain the innovation and is not tried; the rest
        are ranked standardised. None where the prior or the posterior has no inverse."""
        layout = self._layout
        statistics = layout.statistics
        if not kernel.scores(P_prior, A, layout.idx, s, s_prior, layout.rows, self.dt_last, statistics):
            return []
        scored = []
        for (family, _), k, statistic in zip(layout.families, layout.dof, statistics.tolist()):
            if statistic > self._score_quantile[k]:
                scored.append(((statistic - k) / math.sqrt(2.0 * k), family))
        return [family for _, family in sorted(scored, reverse=True)]

    def _jumped(self, P: np.ndarray, families: str) -> np.ndarray:
        """``P`` widened by the jump of each family named (several joined by "+")."""
        widened = P.copy()
        for family in families.split("+"):
            for state, var in zip(JUMPS[family], self.jump_var[family]):
                if state in self._jumping:
                    widened[state, state] += var
            if family == "motion":  # a velocity jump during the last interval moved the position with it
                var, dt = self.jump_var[family][0], self.dt_last
                widened[X, X] += var * dt * dt
                widened[X, V] += var * dt
                widened[V, X] += var * dt
        return widened

    def _position_variance(self) -> float:
        """Variance of the reported position (the carriage's: the image's less the camera's place and the
        lens's slide, which the state carries; with the grating only checked, the place is not a state)."""
        return self.P.item(X, X)

    def _lens(self, s_prior: np.ndarray, P_prior: np.ndarray) -> None:
        """The stretch as a filter following the lens at its fastest declared rate holds it (mean and variance; the
        estimate follows the likely rate, which such a lens outruns): its variance grown at that rate over the
        interval, then the frame's own reading of the stretch taken in, with the information the frame gave the
        estimate's stretch (the marginal's posterior less its prior, over the model's own error there as the
        position's bound counts it) at the value it moved it towards (what it moved it by, over its gain).
        ``s_prior``, ``P_prior``: the state and covariance predicted to the frame."""
        if self.grating != "none":
            return
        lens_var = self._lens_var + self.settings.stretch_rate_most ** 2 * self.dt_last
        posterior, prior = self.P.item(M, M), P_prior.item(M, M)
        if 0.0 < posterior < prior:
            reading = s_prior.item(M) + (self.s.item(M) - s_prior.item(M)) / (1.0 - posterior / prior)
            # (the reading errs by the model's own error at the frame's place, as its position does: a lab strip's
            # model erring three floors read ±2,500 ppm of stretch on a steady run, taken as the lens's)
            gained = (1.0 / posterior - 1.0 / prior) / (1.0 + self._model_share(self.s.item(X)))
            taken = 1.0 / (1.0 / lens_var + gained)
            self._lens_m = taken * (self._lens_m / lens_var + gained * reading)
            lens_var = taken
        self._lens_var = lens_var

    def _disagreeing(self, nu: float, var: float, x_mm: float) -> bool:
        """The grating's reading less the frame's position (``nu``, mm) with the variance the frame states for it
        (``var``), added to the last ``check_window`` frames read; whether their mean disagrees beyond the same
        quantile as one frame's. A drift of the image against the carriage by less than a bound a frame (a lens
        warming slides the image, a print growing) is there frame after frame; one frame's test passes most of them,
        their mean does not. What of a frame's error persists over the window is what calibration's sweep measured
        to persist over the distance the window travelled (:func:`_persistence`; at rest, all of it): a fixed
        pattern on the sensor or the print repeats where the frames overlap. No test where calibration measured
        none."""
        persist = self._persist
        if persist is None:
            return False
        window, places = self._check, self._check_places
        if len(window) >= self._check_length:
            gone, gone_var = window.popleft()
            places.popleft()
            self._check_sum -= gone
            self._check_var -= gone_var
        window.append((nu, var))
        places.append(x_mm)
        self._check_sum += nu
        self._check_var += var
        n = len(window)
        if n < self._check_length:
            return False
        mean = self._check_sum / n
        least = self.settings.check_persist_least
        allowed = self.z_two2 * (self._check_var / n)
        if mean * mean <= allowed * (least + (1.0 - least) / n):  # (within it at the least share: within it at any)
            return False
        share = max(_interpolated(max(places) - min(places), persist[0], persist[1]), least)
        return mean * mean > allowed * (share + (1.0 - share) / n)

    def _slide_variance(self) -> float:
        """What the lens's slide L·m adds to the position's variance, without the grating (fused, the grating reads
        the carriage; checked, its test judges the slide). The lever is a prior no frame narrows, held at nought
        (not solved), so the position takes no slide out and errs by L·m: its expected square is σ_L²·E[m²], with
        E[m²] the larger of what the frames allow were the lens drifting at its fastest declared rate (_lens: its
        mean² and variance) and the estimate's own m̂² and variance."""
        if self.grating != "none":
            return 0.0
        P, drifted = self.P, self._lens_m * self._lens_m + self._lens_var
        return float(P[L, L] * max(drifted, self.s[M] * self.s[M] + P[M, M]))

    def _estimate(self, t: float, stats: list, test: float, mode: str, reason_jump: str | None,
                  reference_mm: float) -> FrameEstimate:
        """The frame's record from the posterior just embedded (its σ in ``_sigma``)."""
        settings = self.settings
        # plain Python numbers from here: this runs for every frame
        s = self.s.tolist()
        sigma = self._sigma.tolist()
        xinfo, used, rejected, residual = (stats[kernel.S_XINFO], stats[kernel.S_USED], stats[kernel.S_REJECTED],
                                           stats[kernel.S_RESIDUAL])
        # The frame's own variance of the position as the update weighed its samples (their noise times the
        # calibration's χ² level there: kernel.U_LEVEL), and the noise floor (the noise alone: the Cramér–Rao bound).
        level = self.params.item(U_LEVEL)
        floor2 = 1.0 / xinfo if xinfo > 0 else math.inf
        floor = math.sqrt(floor2 / level)
        # What a frame's position errs by is what its calibration measured against the grating (the floor, widened
        # by a stream's quantisation and the model's own error there), not what the χ² level of its gray values says
        # (a misfit of the gray values need not move the position as much, nor as little): over the image's share
        # of the position (a fused grating pins the rest) the one is taken for the other, either way.
        var_image = self._position_variance()
        model_var = self._model_variance(s[X], var_image, xinfo, level)
        slide_var = self._slide_variance() if self.grating == "none" else 0.0  # (its own answer with the grating)
        var_x = var_image + model_var + slide_var
        stale, reason, message = False, "", ""
        self._drift_only = False
        checked = self.grating == "check"
        if test > 1.0:
            stale = True
            reason = REASON.get((reason_jump or "").split("+")[0], "") or ("transients" if rejected else "light")
            message = f"innovation χ² {test:.2f}x its quantile at the false-alarm rate"
        if checked and reference_mm == reference_mm:
            nu = reference_mm - s[X]
            var_nu = var_x + self.grating_var
            drifting = self._disagreeing(nu, var_nu, s[X])
            if nu * nu > self.z_two2 * var_nu:
                stale, reason = True, reason or "scale"
                message = message or f"camera and grating disagree by {nu * 1e3:+.2f} µm"
            elif drifting:
                mean = self._check_sum / len(self._check)
                self._drift_only = not stale
                stale, reason = True, reason or "scale"
                message = message or (f"camera and grating disagree by {mean * 1e3:+.2f} µm on average over the last "
                                      f"{len(self._check)} frames")
        bound_factor = self.bound_factor
        vouched = 0.0  # (of the position's variance: what a band the motion told from the position carries)
        if s[BE] > 0.0 and self.grating == "none" and self._band_held(s, sigma):
            # A band held on the pixels while the print carried the image across it is the camera's (a veil on the
            # window, a shadow that stays): its edges and the position no longer trade, so what its states carry of
            # the position is the bound's to state, as a lens's slide is, not a change to flag.
            vouched = kernel.carried(self.P, self._band_states, X)
        elif s[BE] > 0.0 and self.grating == "none":
            # A band in view and no grating: its edges and the position trade over less than a period, and a band
            # entered from a frame's search may sit in a wrong pairing of the two that passes the test (read, the
            # grating tests the position; fused, it pins it): the frame is said to be in its light, not vouched for,
            # until the motion has told the two apart (_band_held).
            stale, reason = True, reason or "light"
            message = message or "a band of shadow or veil in view, no grating to check the position against"
        # A position the frame cannot vouch for (its variance carried by what its image cannot see) is flagged with
        # what carries it; where the grating is read and checked its test above is the position's test, and a frame
        # it finds where the image put it is vouched for by it. A bound carried by the model's own error at the
        # frame's place is what calibration measured there against the grating: the bound states it, and nothing
        # changed (flagged, a steady run without the grating on a model erring a few floors in places was flagged
        # on nearly every frame). Without the grating, what no frame can see of the carriage against the image (the
        # lens's slide, the camera's creep on its mount) is the bound's to state, not a change to flag: flagged, a
        # steady run was flagged on every frame after half a minute, its bound grown as the declared rates allow.
        if self._changed and not (checked and reference_mm == reference_mm):
            held = var_x - slide_var - self._stated(t) - vouched
            if held > settings.dominance * floor2 * bound_factor ** 2 and not model_var > held - model_var - floor2:
                carried = self._carrier()
                if carried:
                    stale, reason = True, reason or carried
                    message = message or f"the position's bound is carried by the {carried} state"
        focus_sigma = sigma[B]
        shown = abs(s[B]) > self.z_two * focus_sigma
        # (by position, in the fields' order, made from the one tuple: by keyword, or through the record's own
        # constructor, it cost a frame a microsecond or two; tuple.__new__ is what _make calls, less its count of
        # the fields, which this one tuple has by construction)
        return tuple.__new__(FrameEstimate, (
            t, s[X], math.sqrt(var_x),  # t, x_mm, crlb_mm
            floor * bound_factor, True, stats[kernel.S_RMS],  # floor_mm, locked, rms_gray
            residual / max(used, 1.0), float(test), int(rejected),  # chi2, test, rejected_px
            int(stats[kernel.S_ITER]), s[G], s[OFS],  # iterations, gain, offset_gray
            s[B] if shown else math.nan, focus_sigma if shown else math.nan,  # focus_px2, focus_sigma_px2
            s[M], sigma[M], s[C], sigma[C],  # stretch, stretch_sigma, place_mm, place_sigma_mm
            mode, False, stale, reason, message,  # mode, repeated, stale, stale_reason, message
            tuple(s), tuple(sigma),  # state, sigma
            math.sqrt(slide_var) if self.grating == "none" else math.nan))  # slide_mm

    def _stated(self, t: float) -> float:
        """What of the position's variance the bound states without a flag, without the grating: what the states no
        frame sees carry of it, the lens's slide wholly (its stretch seen, or the fastest the lens may drift, times a
        lever no frame sees) and the camera's place on the carriage up to what its declared creep allows since the
        estimate started (beyond that, a knock the test found carries it: flagged until the frames settle it); and
        where calibration saw the light walk from frame to frame, what the light carries (the rig's own precision)."""
        if self.grating != "none":
            return 0.0
        slide = kernel.carried(self.P, self._slide_states, X)
        crept = self.grating_var + self.settings.place_rate ** 2 * max(t - self._t_start, 0.0)
        walked = 0.0 if self._walking_light is None else kernel.carried(self.P, self._walking_light, X)
        return slide + min(max(kernel.carried(self.P, self._unseen_states, X) - slide, 0.0), crept) + walked

    def _anchored(self, P: np.ndarray, stats: list) -> bool:
        """Whether the position ``P`` holds is the frame's to say (its variance within the dominance share of the
        frame's own noise floor), not carried by the state's memory of what the frames cannot see: only then
        does what a frame leaves at a sample speak of the sample, and the sensor's map learn from it."""
        xinfo = stats[kernel.S_XINFO]
        return xinfo > 0 and P[X, X] * xinfo <= self.settings.dominance

    def _model_variance(self, x_mm: float, var_image: float, xinfo: float, level: float) -> float:
        """What the bound adds to the posterior's variance ``var_image`` of the position: the frame's own share in it
        taken at what calibration measured (:meth:`_frame_variance`) instead of as its samples were weighed (either
        sign; ``xinfo``: the frame's information on the position, its samples weighed at ``level``)."""
        if not xinfo > 0:
            return 0.0
        at = self._variance_at  # (the frame's test and its bound ask the same)
        if at[0] == x_mm and at[1] == var_image and at[2] == xinfo and at[3] == level and at[4] is self._reach:
            return at[5]
        share = min(var_image * xinfo, 1.0)
        var = (self._frame_variance(x_mm, xinfo, level) - 1.0 / xinfo) * share * share
        self._variance_at = (x_mm, var_image, xinfo, level, self._reach, var)
        return var

    def _frame_variance(self, x_mm: float, xinfo: float, level: float) -> float:
        """The variance of a frame's position at ``x_mm`` alone, as calibration measured it against the grating: the
        noise floor (the frame's information ``xinfo`` with its samples weighed by the noise times ``level``)
        widened by a stream's quantisation and the model's own error there."""
        return self.bound_factor ** 2 * (1.0 + self._model_share(x_mm)) / (xinfo * level)

    def _model_share(self, x_mm: float) -> float:
        """The model's own error power at ``x_mm`` over the noise floor's (ratio² − 1 of its calibration); where the
        frame may be at several places (_places), their mean (each as likely: the variance of what it errs by)."""
        at = self._share_at  # (the frame's bound and its test ask the same)
        if x_mm == at[0] and at[1] is self._reach:
            return at[2]
        edges, shares, whole = self.model_error
        if not edges:
            return whole
        places = self._places(x_mm) if self._folded else (x_mm,)
        total = 0.0
        for place in places:
            total += shares[min(bisect.bisect_right(edges, place) - 1, len(shares) - 1)] \
                if edges[0] <= place <= edges[-1] else whole
        self._share_at = (x_mm, self._reach, total / len(places))
        return self._share_at[2]

    def _carrier(self) -> str:
        """The family whose states carry most of the position's variance (what pinning them would remove:
        kernel.carried)."""
        banded = self.idx is self.idx_band
        carriers = self._carriers.get(banded)
        if carriers is None:  # (per set of states solved: the plain one, and a band's while one is in view)
            solved = set(self.idx.tolist()) | self._drifts  # (a drift's rate carries the state it drifts)
            carriers = self._carriers[banded] = [
                (name, np.array([state for state in states if state in solved], dtype=np.int64))
                for name, states in CARRIERS if solved.intersection(states)]
        best, family = 0.0, ""
        for name, states in carriers:
            removed = kernel.carried(self.P, states, X)
            if removed > best:
                best, family = removed, name
        return family

    def _unplaced(self, t: float, stats: np.ndarray | list, test: float, why: str,
                  repeated: bool = False) -> FrameEstimate:
        nan = math.nan
        return FrameEstimate(t=t, x_mm=nan, crlb_mm=nan, floor_mm=nan, locked=False,
                             rms_gray=float(stats[kernel.S_RMS]), chi2=nan, test=float(test),
                             rejected_px=int(stats[kernel.S_REJECTED]), iterations=int(stats[kernel.S_ITER]),
                             gain=nan, offset_gray=nan, focus_px2=nan, focus_sigma_px2=nan, stretch=nan,
                             stretch_sigma=nan, place_mm=nan, place_sigma_mm=nan, mode="", repeated=repeated,
                             stale=not repeated,
                             stale_reason="" if repeated else "transients" if stats[kernel.S_REJECTED] else "light",
                             message=f"not placed: {why}", state=tuple(float(v) for v in self.s),
                             sigma=tuple(float(v) for v in np.sqrt(np.maximum(np.diag(self.P), 0.0))))

    def _acquire(self, y: np.ndarray, mask: np.ndarray, t: float, reference_mm: float) -> None:
        """Start from the grating where it is read, else from the best of a grid over the stroke."""
        if math.isfinite(reference_mm):
            self.start(reference_mm, t, max(self.settings.grating_sigma, 0.01 * self.model.period_mm))
            return
        lo, hi = (float(v) for v in self.model.info.get("stroke_mm", self.model.stroke_range_mm))
        if not hi > lo:
            lo, hi = float(self.model.stroke_range_mm[0]), float(self.model.stroke_range_mm[1])
        step = self.model.period_mm / ACQUIRE_GRID_PER_PERIOD
        grid = np.arange(lo, hi + step, step)
        values, _ = self.evaluator.evaluate(grid)
        w = mask
        ones, yy, y1 = w.sum(), (w * y * y).sum(), (w * y).sum()
        ff, f1, yf = (values * values) @ w, values @ w, values @ (w * y)
        det = np.maximum(ff * ones - f1 * f1, 1e-300)
        gain = (yf * ones - f1 * y1) / det
        explained = (yf * yf * ones - 2.0 * yf * y1 * f1 + y1 * y1 * ff) / det
        cost = yy - explained + np.where(gain > 0.0, 0.0, np.inf)
        self.start(float(grid[int(np.argmin(cost))]), t, step)
        self.P[G, G], self.P[OFS, OFS] = 1.0, (0.5 * max(self.mean_gray, 1.0)) ** 2  # the light unknown too

    def _warm(self) -> None:
        """Compile (or load) the kernel now, at model install, not on a live frame. (Every array it passes is
        defined: what the maps' calls leave behind is reset, but a value read from memory never written would be
        whatever it holds.)"""
        y = np.zeros(self.n_values)
        self.start(0.5 * sum(self.model.stroke_range_mm), 0.0, 1.0)
        self._solve(y, self.mask.copy(), self.s.copy(), self.P.copy(), math.nan)
        self._solve(y, self.mask.copy(), self.s.copy(), self.P.copy(), 0.0)
        kernel.predict(self.s.copy(), self.P.copy(), 0.01, 1.0, 1.0, self.rates2, np.zeros(4))
        kernel.embed(self.P.copy(), np.eye(self.idx.size), self.idx, self._sigma, np.zeros(N_STATE))
        kernel.carried(self.P, self.idx, X)
        kernel.longest_run(self._y, self.model.n_pixels, 1.0)
        for layout in (self._layout_plain, self._layout_band):
            kernel.scores(self.P, np.eye(layout.idx.size), layout.idx, self.s, self.s, layout.rows, 0.01,
                          layout.statistics)
        grid = np.zeros((2, self.n_values))
        kernel.agreement(self._y, self.mask, grid, 1, 0.0, 1.0, AGREED_ROUNDS, np.empty(2), np.empty(2), np.empty(2))
        for kind in FRAME_TYPES:  # each kind of frame a camera delivers, compiled for now
            kernel.row_mean(np.zeros((2, self.model.n_pixels), dtype=kind), self._y)
        self._y[:] = 0.0
        kernel.in_range(self._y, 0.0, 1.0, self.mask, self._masked)
        MountWatch(1.0, 1.0).add(0.0, 0.0, 1.0)  # (the mount's compiled calls, whatever the mode)
        step_test(np.arange(4.0), np.zeros(4), np.ones(4), 1.0)
        kernel.residuals(self.s, self._y, self.mask, self.rho, self.pixels, self.params, self.model_args, self.scratch,
                         self._noise_var)
        self.sensor.land(self._y, self.mask)  # (every sample fails on a frame of zeros: the map holds back)
        self.sensor.learn(self._y, self._y, self._y, self._zeros, self._noise_var, self.mask, 0.0)
        self.sensor.active = True
        self.sensor.seen(self._y, self.mask)
        self.sensor.reset()
        self.print_map.land(np.zeros(self.n_values, dtype=np.bool_), 0.0, float(self.s[X]), 0.0)
        self.print_map.seen(self._y, self.mask, float(self.s[X]), 0.0, 0.0)
        self.print_map.learn(self._y, self._y, self._y, self._zeros, self._noise_var, self.mask, 0.0)
        self.print_map.reset()
        self.started = False


Progress = Callable[[float, str], None]


def track(model: FourierModel, frames: np.ndarray, t: np.ndarray, reference: np.ndarray | None = None,
          grating: str = "check", robust: bool = True, settings: EstimatorSettings | None = None,
          axis_px: float | None = None, progress: Progress | None = None,
          estimator: Estimator | None = None, stage_phases: np.ndarray | None = None) -> list[FrameEstimate]:
    """Every frame of a recording through one estimator, in order: the live recursion, batched. ``estimator``:
    the one to run (made from the other arguments where None), to read what it learned afterwards."""
    if estimator is None:
        estimator = Estimator(model, settings=settings, grating=grating, robust=robust, axis_px=axis_px,
                              stage_phases=stage_phases)
    grating = estimator.grating
    n = frames.shape[0]
    reference = np.full(n, np.nan) if reference is None or grating == "none" else np.asarray(reference, float)
    times, readings = np.asarray(t, dtype=np.float64).tolist(), reference.tolist()  # plain numbers, made once
    out: list[FrameEstimate] = []
    update, append = estimator.update, out.append  # (looked up once: the loop runs a frame's worth of calls)
    if progress is None:
        for k, frame in enumerate(frames):
            append(update(frame, times[k], readings[k]))
        return out
    for k in range(n):
        append(update(frames[k], times[k], readings[k]))
        if k % 1000 == 999 or k == n - 1:
            progress((k + 1) / n, f"frame {k + 1} of {n}")
    return out


def _calibration_reference(model: FourierModel, rec: "Recording") -> np.ndarray | None:
    """Calibration's grating readings at each exposure (its latch's skew taken out), None where it read none."""
    from graytrack.core.timing import model_reference

    reference = np.asarray(rec.reference, dtype=np.float64)
    if not np.isfinite(reference).any():
        return None
    if float(model.info.get("reference_skew_s", 0.0)):
        reference = model_reference(model, rec.t, reference)
    return reference


def calibration_error(model: FourierModel, rec: "Recording") -> dict | None:
    """The model's own error along the stroke as the estimator errs with it: calibration's recording ``rec`` tracked
    with the grating read and checked (each position the image's own), against the grating, over the bound the
    estimator states without the model's error (its noise floor widened by a stream's quantisation) and the
    grating's rounding: stretch by stretch what repeats at the place (core/adequacy.py ``error_profile``), and
    ``whole``, the same over the stroke. Today's tracking measures its own (core/calibration_line.py): the two paths
    err differently where the model misses (a glare read 23 floors by the one, 5.5 by the other), and the bound of
    each is its own error's. None without a grating or with too few frames placed."""
    from graytrack.core.adequacy import PROFILE_FRAMES, error_profile, shared_error
    from graytrack.core.noise import reference_resolution_mm
    from graytrack.core.recording import acceleration_phases

    reference = _calibration_reference(model, rec)
    if reference is None:
        return None
    step = float(rec.meta.get("grating_resolution_mm", 0.0) or 0.0) or reference_resolution_mm(reference)

    def erred(grating: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(places, error less its mean, bound²) of calibration's frames tracked as a run is in the mode ``grating``
        ("check", or "none": placed up to whole periods, taken out), None where too few are placed."""
        estimator = Estimator(model, settings=EstimatorSettings().for_recording(rec.meta), grating=grating,
                              stage_phases=acceleration_phases(rec.meta))
        estimates = track(model, rec.frames, rec.t, reference, estimator=estimator)
        x = np.array([e.x_mm for e in estimates])
        floor = np.array([e.floor_mm for e in estimates])
        usable = np.isfinite(x) & np.isfinite(reference) & np.isfinite(floor)
        if usable.sum() < 2 * PROFILE_FRAMES:
            return None
        error = x[usable] - reference[usable]
        error -= model.period_mm * np.round(float(np.median(error)) / model.period_mm)
        # (the grating's rounding is in the error)
        return reference[usable], error - error.mean(), floor[usable] ** 2 + step * step / 12.0

    def measured(places: np.ndarray, error: np.ndarray, bound2: np.ndarray) -> dict | None:
        profile = error_profile(places, error, bound2)
        if profile is None:
            return None
        shared = float(np.mean(shared_error(error[np.argsort(places)])))
        whole = round(math.sqrt(max(1.0 + shared / float(np.mean(bound2)), 0.0)), 3)
        return {"edges_mm": profile["edges_mm"], "ratio": profile["ratio"], "whole": whole,
                "persist": _persistence(places, error)}

    def mapped(erred: tuple[np.ndarray, np.ndarray, np.ndarray]) -> dict | None:
        """What of the error the image repeats at each place (the print's marks, a light uneven along the target,
        the model's series missing the print's shape there), and what it leaves: the bound's, measured on frames the
        map was not made from (each frame against the map its neighbours in time made, every other one: a run's
        noise is not calibration's, while what repeats at a place both halves share)."""
        places, error, bound2 = erred
        made_map = error_map(places, error)
        if made_map is None:
            return None
        left_error = np.empty_like(error)
        for half in (0, 1):
            made, read = slice(1 - half, None, 2), slice(half, None, 2)
            other = error_map(places[made], error[made], kept=1.0)
            left_error[read] = error[read] - (0.0 if other is None else
                                              np.interp(places[read], other["x_mm"], other["error_mm"]))
        left = measured(places, left_error, bound2)
        return None if left is None else {**made_map, **left}

    first = erred("check")
    plain = None if first is None else measured(*first)
    if first is None or plain is None:
        return None
    if (made := mapped(first)) is not None:
        plain["map"] = made
    # From the image alone the states follow the frames otherwise than read and checked, and the model's error with
    # them: its own pass says what a frame errs by there before its map is read (``alone``), and makes that map.
    if (alone := erred("none")) is not None:
        if (own := measured(*alone)) is not None:
            plain["alone"] = own
        if (made := mapped(alone)) is not None:
            plain["map_alone"] = made
    return plain


def error_map(x_mm: np.ndarray, error: np.ndarray, kept: float | None = None) -> dict | None:
    """Where the image places the carriage at each place of the stroke against the grating, as calibration's frames
    erred (``{"x_mm": [...], "error_mm": [...]}``: the means of stretches of :data:`core.adequacy.PROFILE_FRAMES`
    frames at their mean places), None where the stretches' means scatter no more than their frames do within them
    (:data:`core.adequacy.ROW_SIGNIFICANCE` standard errors of their spread).

    The model's series holds what is fixed to the pixels; what is fixed to the print and the model misses (its marks,
    ink not equally dark, the light uneven along the target, a pitch not the series' own) moves the image's place by
    as much at that place on every pass. Each mean is shrunk by its own noise's share of the means' spread (a
    Wiener weight: the scatter within a stretch is its measure, no noise model is trusted for it), so that a map that
    barely stands out moves a frame by no more than what it holds."""
    from graytrack.core.adequacy import PROFILE_FRAMES, ROW_SIGNIFICANCE

    if x_mm.size < 4 * PROFILE_FRAMES:
        return None
    order = np.argsort(x_mm, kind="stable")
    stretches = x_mm.size // PROFILE_FRAMES
    cut = stretches * PROFILE_FRAMES
    places = x_mm[order][:cut].reshape(stretches, PROFILE_FRAMES)
    errors = error[order][:cut].reshape(stretches, PROFILE_FRAMES)
    means = errors.mean(axis=1)
    within = float(errors.var(axis=1, ddof=1).mean()) / PROFILE_FRAMES
    between = float(np.var(means, ddof=1))
    if not within > 0.0 or (between - within) / (within * math.sqrt(2.0 / (stretches - 1))) <= ROW_SIGNIFICANCE:
        return None
    kept = 1.0 - within / between if kept is None else kept
    return {"x_mm": [round(float(x), 5) for x in places.mean(axis=1)],
            "error_mm": [round(float(kept * (e - means.mean())), 7) for e in means]}


PERSISTENCE_FRAMES = (2, 4, 8, 16, 32, 64, 128)  # windows over which calibration measures what of its error persists


def _persistence(x_mm: np.ndarray, error: np.ndarray) -> dict:
    """What of a frame's error against the grating persists over a window of frames, by the distance the window
    travelled (calibration's sweep, in time order): for each window of ``PERSISTENCE_FRAMES``, the share p of the
    error's variance its moving mean keeps beyond what a mean of independent errors would (var(mean) = var·(p +
    (1 − p)/n)), at the window's median span; the shares held to rise as the distance shrinks (at rest, all)."""
    var = float(np.var(error))
    distances, shares = [], []
    for n in PERSISTENCE_FRAMES:
        if error.size < 4 * n or not var > 0.0:
            break
        kernel_n = np.ones(n) / n
        mean = np.convolve(error, kernel_n, mode="valid")
        span = float(np.median(np.abs(x_mm[n - 1:] - x_mm[:x_mm.size - n + 1])))
        share = (float(np.mean(mean * mean)) / var - 1.0 / n) / (1.0 - 1.0 / n)
        if span > 0.0:
            distances.append(span)
            shares.append(min(max(share, 0.0), 1.0))
    order = np.argsort(distances, kind="stable")
    distances, shares = [round(distances[k], 6) for k in order], [shares[k] for k in order]
    for k in range(len(shares) - 2, -1, -1):  # (a nearer window keeps no less than a farther one)
        shares[k] = max(shares[k], shares[k + 1])
    return {"distance_mm": distances, "share": [round(share, 4) for share in shares]}


def kept_from_calibration(model: FourierModel, rec: "Recording") -> None:
    """What the estimator keeps from calibration's own recording ``rec`` in the model's info: the sensor's rough
    pattern it measures there (flat_field.py), the print's map it learns (:func:`calibration_print_map`) and the
    model's own error along the stroke as it errs (:func:`calibration_error`), each with those before it, each
    replaced (or removed where none)."""
    made_here = ((FLAT_FIELD, calibration_flat_field), (CALIBRATION_PRINT_MAP, calibration_print_map),
                 (CALIBRATION_ERROR, calibration_error))
    for key, _ in made_here:  # (each is made with what comes before it, not with what an earlier calibration kept)
        model.info.pop(key, None)
    for key, made in made_here:
        if (kept := made(model, rec)) is not None:
            model.info[key] = kept


def calibration_print_map(model: FourierModel, rec: "Recording") -> dict | None:
    """The print's map (:meth:`PrintMap.state`) the estimator learns on calibration's own recording ``rec`` with its
    grating fused, where it learned a mark: the print's own dust and scratches the model's smooth series cannot hold,
    known to every run from its first frame instead of learned again in each (a steady run learns nothing)."""
    from graytrack.core.recording import acceleration_phases

    reference = _calibration_reference(model, rec)
    if reference is None:
        return None
    estimator = Estimator(model, settings=EstimatorSettings().for_recording(rec.meta), grating="fuse",
                          stage_phases=acceleration_phases(rec.meta), survey_sigma=CALIBRATION_SURVEY_SIGMA)
    track(model, rec.frames, rec.t, reference, estimator=estimator)
    if not estimator.print_map.learned().any():
        return None
    estimator.print_map.keep_learned()
    return estimator.print_map.state()


def as_result(estimates: list[FrameEstimate], chi2_calibration: float) -> "TrackResult":
    """The estimates as the command's per-frame columns (core/frame_record.py names them), made once."""
    from graytrack.core.tracking import LockEvent, TrackResult

    # (the records turned into columns at once: one attribute read per record and column cost a frame 3 µs)
    columns = list(zip(*estimates)) if estimates else [()] * len(FrameEstimate._fields)
    where = {name: k for k, name in enumerate(FrameEstimate._fields)}

    def column(name: str, kind: type = float) -> np.ndarray:
        return np.array(columns[where[name]], dtype=kind)

    events = [LockEvent(frame=k, reason=e.message, x_before_mm=math.nan, x_after_mm=math.nan, reacquired=False)
              for k, e in enumerate(estimates) if not e.locked]
    result = TrackResult(x_mm=column("x_mm"), locked=column("locked", bool), rms_gray=column("rms_gray"),
                       crlb_mm=column("crlb_mm"), iterations=column("iterations", np.int64), gain=column("gain"),
                       offset_gray=column("offset_gray"), events=events, chi2=column("chi2"),
                       rejected_px=column("rejected_px", np.int64), stale=column("stale", bool),
                       chi2_calibration=chi2_calibration, repeated=column("repeated", bool),
                       stale_reason=column("stale_reason", object).astype(str),
                       transient_px=np.zeros(len(estimates), dtype=np.int64), focus_px2=column("focus_px2"),
                       focus_sigma_px2=column("focus_sigma_px2"))
    slide_um = column("slide_mm") * 1e3
    if np.isfinite(slide_um).any():
        result.slide_sigma_um = slide_um
    return result


__all__ = ["CALIBRATION_ERROR", "CALIBRATION_PRINT_MAP", "Estimator", "FrameEstimate", "GRATING_MODES", "STATE",
           "as_result", "calibration_error", "calibration_level", "calibration_print_map", "kept_from_calibration",
           "track"]
