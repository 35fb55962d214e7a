"""The ``scale`` watch: the camera against the grating, when frames come with a grating reading.

The model can fit every image perfectly while the target itself has grown or the camera has moved
along the axis: only an outside ruler sees that. This watch feeds each frame's position, grating
reading and bound to a :class:`~graytrack.core.reference_monitor.ReferenceMonitor` and blames
``scale`` while the monitor finds the line camera − grating drifted beyond its uncertainty.

Besides the line, a running mean of camera − grating over the last ``SUSPECT_WINDOW`` frames is
judged against its standard error on every frame: an episode of tens of frames placed several
bounds off the grating (a smudge coming into view, whose core the robust solve sets aside and
whose wings bend the fit while the frame's χ² stays within its noise) is too short for the line,
whose outlier gate leaves such frames out, and too short for the spread over 200 frames
(core/watches/grating.py). While χ² is suspect it blames ``geometry``, else ``scale``.

With an online trim (``track --trim``, the daemon's ``[daemon] trim``) the watch owns the trim
(:class:`~graytrack.core.reference_monitor.Trimmer`) and its owner hands it to the tracker through
its constructor (``LiveTracker(..., watches=)``, ``track(..., watches=)``): a frame is counted once,
drift is measured against the trim in force, and a frame the trim lags by more than its bound is
flagged (core/trim_follow.py).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from graytrack.core.compression import stream_bound_factor
from graytrack.core.reference_monitor import GATE, ReferenceMonitor, Trimmer, TrimEvent, scale_tells
from graytrack.core.chi2_curve import Chi2Curve
from graytrack.core.stretch_follow import StretchFollow, Taken
from graytrack.core.validity import RANK, Decisive, FrameSign
from graytrack.core.watches import _kernels
from graytrack.core.watches.grating import GratingWatch
from graytrack.core.watches.grating import for_model as grating_watch
from graytrack.core.stretch import Measured, chunk_stretches
from graytrack.core.drift_cause import lens_favoured
from graytrack.core.watches.magnification import MagnificationWatch, asked_stretches
from graytrack.core.watches import far_off as far_off_watch
from graytrack.core.watches.far_off import FarOffWatch


# While χ² is suspect no line is fitted, and with χ² quiet the line leaves far frames out as outliers;
# but a camera that disagrees with the grating by this many standard errors (of the frames' bounds, the grating's
# rounding, the calibration line and the
# model's own structure along the stroke), averaged over SUSPECT_WINDOW frames, places its frames
# off whatever the cause: a model 5 % off in period, seen at rest mid-stroke, has its running χ²
# hover at the stale line (1.2026 against 1.2023) and its positions 285 µm (~200 bounds) off,
# which χ² alone calls fresh on 94 % of the frames.
SUSPECT_WINDOW = 20
SUSPECT_LIMIT = 6.0
# ... but while the mean fills for the first time against the calibration's line, its tests are few (at most
# SUSPECT_WINDOW - 1 a run, each on more frames than the last), not one a frame for good: at 4.5 σ they raise a
# false alarm on < 1.4e-4 of runs (6.8e-6 a test). A 16-row print grown 250 ppm starts 1.5 µm (4.5 bounds) off
# the truth, 3.7, 4.8 and 5.4 σ of the mean over its first 1, 2 and 3 frames: at 6 σ all three went unflagged
# (0.6 % of the run), at 4.5 only the first (steady runs: the largest start-up |z| 2.2 on the sweep's rigs)
START_LIMIT = 4.5
STRETCH_Z = 3.0  # a stretch within this many σ of the line's scale, the scale beyond it: the print grew (2: a
# grown paper print named magnification on 10 of 500 frames)
FAR_OFF = "graytrack.core.watches.far_off"  # the untrimmed camera far off the grating (a wrong model's scale)
# frames in the line of camera − grating kept beside the monitor's while it has drifted: a slide that turned (a
# lens's temperature cycle) tilts this line at once, while the monitor's 500 frames average its rise and fall to
# no scale (the paper cycle's window scale crossed zero at frame ~310 and stayed within 1000 ppm for 140 frames)
LOCAL_WINDOW = 100


class ScaleWatch:
    """``observe(sign) -> "scale" | None`` from ``sign.x_mm``, ``sign.reference_mm``, ``sign.information``.

    With a ``trimmer`` (an online trim: ``track --trim``, the daemon's ``[daemon] trim``) the watch
    feeds the trim's monitor itself, so a frame is counted once and drift is measured against the
    trim in force; a frame is also blamed while the trim lags it by more than its bound. Its owner
    reads what the trim did to each frame from :attr:`last` (live) or :attr:`log` (a recording)."""

    family = "scale"
    reads = ("chi2_suspect", "placed", "x_mm", "reference_mm", "information", "stretch", "chi2", "rows_averaged")

    def __init__(self, monitor: ReferenceMonitor, feeds: bool = True, bound_scale: float = 1.0,
                 trimmer: Trimmer | None = None, log: bool = False,
                 magnification: MagnificationWatch | None = None, grating: GratingWatch | None = None,
                 stretch: StretchFollow | None = None, local: ReferenceMonitor | None = None,
                 far_off: FarOffWatch | None = None) -> None:
        if trimmer is not None and trimmer.monitor is not monitor:
            raise ValueError("a scale watch's trimmer must read the watch's own monitor")
        if trimmer is not None and far_off is not None:
            raise ValueError("a trimmed scale watch judges the camera far off against its trim: it carries no far-off")
        self.monitor = monitor
        self._off = Disagreement(monitor)
        self.feeds = feeds
        self.bound_scale = bound_scale  # the frames' bound over the sensor's (a JPEG stream's quantisation)
        self.trimmer = trimmer
        # with a trim, the magnification watch judges the stretch the trim does not account for and the
        # grating watch the trimmed positions: they must see the trim in force at each frame, so they
        # are stepped here, in place of the tracker's own (``replaces``: core/validity.py monitor_for)
        self.magnification, self.grating = magnification, grating
        self.replaces = tuple(type(watch).__module__ for watch in (magnification, grating) if watch is not None)
        if trimmer is not None:  # the camera far off the grating is judged against the trim in force (the
            # running mean's limit below): untrimmed, a lens's slide of 94 µm, trimmed to the bound, read as
            # a model of the wrong scale on 58 % of a 16-row run's frames
            self.replaces += (FAR_OFF,)
        # untrimmed, the far-off judgement stepped here (``replaces``), so that the camera far off is named with
        # what drifted the line (:meth:`_far_named`): a lens's slide 3000 ppm × 500 px from the axis, hundreds of
        # µm on a 16-row strip, had 295 of 490 flagged frames named ``scale`` (a wrong model) by the far-off alone
        self.far_off = far_off
        if far_off is not None:
            self.replaces += (FAR_OFF,)
        # the lens's stretch the tracker takes out of each frame (core/stretch_follow.py): the tracker finds
        # it here (``track(..., watches=)``), and this watch reads what each frame had taken out
        self.stretch_follow = stretch
        # untrimmed, the line of the last LOCAL_WINDOW frames since the monitor's drifted (:meth:`_stretched_by`)
        self.local = local
        self.events: list[tuple[int, TrimEvent]] = []  # (frame, a change of the trim), for the owner to drain
        self.last = Applied()  # what the trim did to the last frame
        self.log: list[Applied] | None = [] if log else None  # ... to every frame, when asked for
        self._frame = 0

    @classmethod
    def for_model(cls, model, reference_resolution_mm: float = 0.0, trim: bool = False, log: bool = False,
                  **options) -> "ScaleWatch":
        """A watch centred on the model's calibrated stroke (its scale is measured about the centre,
        its floor over the whole stroke); ``reference_resolution_mm``: the grating's step, if known;
        ``trim``: with an online trim of its own."""
        monitor = ReferenceMonitor.for_model(model, reference_resolution_mm, **options)
        if not trim:  # the stretch judged beside the line (:meth:`_stretched_by`)
            local = ReferenceMonitor.for_model(model, reference_resolution_mm, **{**options, "window": LOCAL_WINDOW})
            return cls(monitor, bound_scale=stream_bound_factor(model.info), log=log,
                       magnification=MagnificationWatch.for_model(model), local=local,
                       far_off=far_off_watch.for_model(model))
        chi2_calibration = float(model.info.get("calibration_chi2") or 1.0)
        return cls(monitor, bound_scale=stream_bound_factor(model.info), trimmer=Trimmer(monitor), log=log,
                   magnification=MagnificationWatch.for_model(model),
                   grating=grating_watch(model, chi2_calibration, Chi2Curve.from_info(model.info)),
                   stretch=StretchFollow.for_model(model))

    def observe(self, sign: FrameSign) -> str | None:
        return self.step(sign.chi2_suspect, sign.placed, sign.x_mm, sign.reference_mm, sign.information,
                         sign.stretch, sign.chi2, sign.rows_averaged)

    def step(self, chi2_suspect: bool, placed: bool, x_mm: float, reference_mm: float,
             information: float, stretch=None, chi2: float = 0.0, rows_averaged: int = 1) -> str | None:
        # While χ² says the images changed, a disagreement with the grating is its consequence, not a
        # scale: those frames are not fed. But a disagreement already found stays a flag: the camera
        # is off the grating and the images are not the calibration's, so the model does not describe
        # the rig (geometry), even while χ² has not yet crossed its own stale limit.
        # A run of frames off the grating by many of their bounds is judged on every frame: with χ²
        # quiet the line's outlier gate would leave such frames out until it calls them a jump.
        bound = self.bound_scale / math.sqrt(information) if placed and information > 0 else float("nan")
        # a trim learns from every placed frame, as the daemon's always did: a drift that raises χ² (a
        # stretch of the image) is what it has to follow
        trimmer = self.trimmer
        feed = self.feeds and placed and (trimmer is not None or not chi2_suspect)
        behind = False
        if trimmer is not None:
            event = trimmer.feed(x_mm, reference_mm, bound, feed)
            if event is not None:
                self.events.append((self._frame, event))
            drifted, behind = trimmer.drifted, trimmer.behind(bound)
            trimmed, added = trimmer.step(x_mm)
            # the running mean of camera − grating against the trim and what follows it
            following = trimmer.following.correction_um if trimmer.trim is not None else 0.0
            far = self._off.add(x_mm - following * 1e-3, reference_mm, math.hypot(bound, added))
            self.last = Applied(trimmed, (x_mm - trimmed) * 1e3 if trimmer.trim is not None else 0.0, added * 1e3)
        else:
            far = self._off.add(x_mm, reference_mm, bound)
            if feed:
                self.monitor.observe(x_mm, reference_mm, bound)
            drifted = self.monitor.stale
            if self.local is not None:
                self._step_local(drifted, feed, x_mm, reference_mm, bound)
        self._frame += 1
        verdict = None
        if chi2_suspect:
            verdict = "geometry" if drifted or far else None
        elif drifted or far or behind:
            verdict = self.family
        if self.log is not None:
            self.log.append(dataclasses.replace(self.last, flagged=verdict is not None, drifted=drifted)
                            if trimmer is not None else Applied(x_mm, flagged=verdict is not None, drifted=drifted))
        verdicts, cause = [verdict], None
        if self.magnification is not None:
            *verdicts, cause = self._stretch_step(placed, x_mm, stretch, verdict)
        if self.grating is not None:
            trimmed = self.last.x_mm if trimmer is not None and trimmer.trim is not None else x_mm
            verdicts.append(self.grating.step(placed, reference_mm, trimmed, information, chi2, chi2_suspect))
        if self.far_off is not None:
            far_family = self.far_off.step(placed, reference_mm, x_mm, information, rows_averaged)
            if far_family is not None:
                return self._far_named(far_family, cause)
        return min((v for v in verdicts if v is not None), key=RANK.__getitem__, default=None)

    @staticmethod
    def _far_named(far: str, cause: str | None) -> Decisive:
        """The carried far-off verdict (untrimmed), named with what drifted the line: a lens's slide is
        ``magnification``; anything else far off is the model's scale (a model of another period or pitch,
        whose stretch the line's scale matches, or a print grown: core/watches/far_off.py). Decisive either
        way: the light and focus watches only describe how the frames fail so far off."""
        return Decisive("magnification" if cause == "lens" else far)

    def _stretch_step(self, placed: bool, x_mm: float, stretch,
                      verdict: str | None = None) -> tuple[str | None, str | None, str | None]:
        """The carried magnification watch's step beside the line: (the line's verdict, renamed
        ``magnification`` when a lens drifted it; the stretch's verdict, None where the line names a
        print's growth; what stretched the image, :meth:`_stretched_by`)."""
        taken = self.stretch_follow.taken() if self.stretch_follow is not None else Taken()
        stretched = self.magnification.step(placed, x_mm, stretch, *_accounted(self.trimmer, taken))
        # :meth:`_named` written out: live frames through the helper measured 0.93-0.95x main's p50 (disturbed,
        # five side-by-side runs), 0.99-1.00x so (two); the cause is not understood
        cause = self._stretched_by()
        if stretched is not None and cause == "print":
            return verdict, None, cause
        if verdict == self.family and cause == "lens":
            return "magnification", "magnification", cause
        return verdict, stretched, cause

    def _named(self, verdict: str | None, stretched: str | None, cause: str | None) -> tuple[str | None, str | None]:
        """:meth:`_stretch_step`'s answer (as it spells it out) from the line's verdict, the stretch's and what
        stretched the image: a chunk's frames (:meth:`_stepped`)."""
        if stretched is not None and cause == "print":
            return verdict, None
        if verdict == self.family and cause == "lens":
            return "magnification", "magnification"
        return verdict, stretched

    def _step_local(self, drifted: bool, feed: bool, x_mm: float, reference_mm: float, bound: float) -> None:
        """The local line follows the frames while the monitor's line has drifted, and starts again
        once it holds: a steady run never feeds it."""
        local = self.local
        if not drifted:
            if local.frames:
                local.reset()
        elif feed:
            local.observe(x_mm, reference_mm, bound)

    def _stretched_by(self) -> str | None:
        """What stretches the image while the line camera − grating has drifted (untrimmed: the trim's
        scale is taken out of the stretch instead, :func:`_accounted`): ``"print"`` when the
        magnification watch's stretch is the line's scale (a print grown by g reads the scale −g and
        stretches its image by the same −g; the two within :data:`STRETCH_Z` of their σ, the scale
        beyond it), ``"lens"`` when a stretch beyond :data:`STRETCH_Z` of its σ is not (a lens's
        magnification m stretches the image with no such slope: its slide, m × the axis's distance,
        is the same all along the stroke, and what of it the line reads as a scale while the stage
        sweeps, the slide's growth in time over the speed, does not match the stretch: −2800 ppm for
        a 0.15 % ramp over 10 s on the paper rig, its stretch 0 to 1500), else None. A 16-row print
        grown 250 ppm had 391 of 500 frames named ``magnification`` under the line's ``scale``; the
        paper rig's lens ramp 289 frames ``scale`` before the stretch's own mean told it. Between the two,
        the cause that explains the stretch and the line's scale together best (core/drift_cause.py): a
        scale of thousands of ppm with no stretch to match is no print's, and no grating's or mount's."""
        line = self.monitor.estimate
        if self.trimmer is not None or not self.monitor.stale or line is None:
            return None
        return self._cause(line.scale_ppm, line.covariance[2])

    def _cause(self, scale_ppm: float, scale_var: float) -> str | None:
        """:meth:`_stretched_by` of a drifted line with this scale and variance (untrimmed), the local line
        (:meth:`_step_local`) as it stands."""
        monitor = self.monitor
        mean, sigma = self.magnification.so_far()  # before the watch's own frames are in, the frames' so far
        if not math.isfinite(sigma):
            return None
        base = monitor.calibration
        scale, scale_var = _since_calibration(scale_ppm, scale_var, base)
        limit2 = STRETCH_Z * STRETCH_Z
        if scale * scale > limit2 * scale_var and (mean - scale) ** 2 <= limit2 * (scale_var + sigma * sigma):
            return "print"
        if mean * mean > limit2 * sigma * sigma:
            return "lens"
        lines = [(scale, scale_var)]
        local = self.local.estimate if self.local is not None else None
        if local is not None:
            lines.append(_since_calibration(local.scale_ppm, local.covariance[2], base))
        if any(lens_favoured(mean, sigma, *line) for line in lines):
            return "lens"
        return None

    def step_many(self, columns, n: int) -> list[str | None]:
        """:meth:`step` of ``n`` frames at once (the monitor's :meth:`~ReferenceMonitor.observe_many`):
        the running mean of each frame reads the monitor's scatter as it stood before the frame, as
        :meth:`step` does, and its :attr:`log` gets what :meth:`step` would have appended."""
        if self.trimmer is not None or self.grating is not None:
            return None  # frame by frame: a trim follows each frame
        if columns.array("chi2_suspect", bool).any():
            return self._stepped(columns)  # a suspect run reads the monitor's verdict
        carried = self.magnification
        saved = (self.monitor.snapshot(), self._off.snapshot()) if carried is not None else None
        information = columns.array("information", np.float64)
        placed = columns.array("placed", bool)
        feed = placed if self.feeds else np.zeros(n, dtype=bool)
        positive = placed & (information > 0)
        bound = np.where(positive, self.bound_scale / np.sqrt(np.where(positive, information, 1.0)), np.nan)
        x_mm, reference_mm = columns.array("x_mm", np.float64), columns.array("reference_mm", np.float64)
        scatter = np.empty(n)
        drifted = self.monitor.observe_many(x_mm, reference_mm, bound, feed, scatter=scatter)
        stale = self._off.add_many(x_mm, reference_mm, bound, scatter) | drifted
        self._frame += n
        if saved is not None and stale.any():  # the line drifted here: the stretch is named against it frame by frame
            self.monitor.restore(saved[0])
            self._off.restore(saved[1])
            self._frame -= n
            return self._stepped(columns)
        if self.local is not None and self.local.frames:  # the line held on every frame: as :meth:`_step_local`
            self.local.reset()
        if self.log is not None:
            self.log.extend(Applied(x, flagged=flagged, drifted=drift)
                            for x, flagged, drift in zip(columns["x_mm"], stale.tolist(), drifted.tolist()))
        if saved is not None:
            # the line held on every frame: the stretch is the magnification watch's alone (its chunk path when
            # it has one: the same as its step frame by frame, nothing accounted for untrimmed)
            many = carried.step_many(columns, n) if hasattr(carried, "step_many") else None
            if many is None:
                many = [self._stretch_step(*row)[1]
                        for row in zip(columns["placed"], columns["x_mm"], columns["stretch"])]
        else:
            many = np.where(stale, self.family, None).tolist() if stale.any() else [None] * n
        return self._far_many(columns, many)  # the line held: nothing drifted it, a camera far off is the scale's

    def _far_many(self, columns, families: list[str | None],
                  causes: list[str | None] | None = None) -> list[str | None]:
        """``families`` of a chunk with the carried far-off judgement's over them (:meth:`_far_named`, each
        frame's ``causes``: what drifted its line, none given while the line held)."""
        if self.far_off is None:
            return families
        far = self.far_off.step_many(columns, len(families))
        if not any(far):
            return families
        causes = causes or [None] * len(families)
        return [family if off is None else self._far_named(off, cause)
                for family, off, cause in zip(families, far, causes)]

    def _stepped(self, columns) -> list[str | None]:
        """:meth:`step` of a chunk (untrimmed) where the line drifted or χ² was suspect: the stretch is named
        against the line frame by frame. The monitor and the running mean still take the chunk at once
        (the line after each frame recorded: all the naming reads of it), the chunk's stretches by one
        compiled call (core/stretch.py, :func:`~graytrack.core.stretch.chunk_stretches`: the same numbers
        as each frame's own call); the carried magnification watch and the naming then go frame by frame,
        as :meth:`step` does (tests/core/test_stretch_fast.py holds the two to the bit)."""
        n = len(columns["x_mm"])
        suspect = columns.array("chi2_suspect", bool)
        information = columns.array("information", np.float64)
        placed = columns.array("placed", bool)
        feed = placed & ~suspect if self.feeds else np.zeros(n, dtype=bool)  # a suspect frame is not fed
        positive = placed & (information > 0)
        bound = np.where(positive, self.bound_scale / np.sqrt(np.where(positive, information, 1.0)), np.nan)
        x_mm, reference_mm = columns.array("x_mm", np.float64), columns.array("reference_mm", np.float64)
        scatter, lines = np.empty(n), np.empty((n, 3))
        drifted = self.monitor.observe_many(x_mm, reference_mm, bound, feed, scatter=scatter, lines=lines)
        far = self._off.add_many(x_mm, reference_mm, bound, scatter)
        self._frame += n
        off = drifted | far  # while χ² is suspect a disagreement is the model's (geometry), else the scale's
        verdicts = np.where(off, np.where(suspect, "geometry", self.family), None).tolist()
        if self.log is not None:
            self.log.extend(Applied(x, flagged=verdict is not None, drifted=drift)
                            for x, verdict, drift in zip(columns["x_mm"], verdicts, drifted.tolist()))
        if self.magnification is None:
            return self._far_many(columns, verdicts)
        entries = list(columns["stretch"])
        asked = asked_stretches(columns)
        m, sigma = chunk_stretches(entries, asked)
        for i, value, spread in zip(asked.tolist(), m[asked].tolist(), sigma[asked].tolist()):
            entries[i] = Measured(value, spread)
        step, cause, name = self.magnification.step, self._cause, self._named
        local = self._step_local if self.local is not None else None
        families, causes = [], []
        for verdict, frame_placed, x, reference, frame_bound, fed, stretch, drift, (has, scale, scale_var) in zip(
                verdicts, columns["placed"], columns["x_mm"], reference_mm.tolist(), bound.tolist(), feed.tolist(),
                entries, drifted.tolist(), lines.tolist()):
            if local is not None:
                local(drift, fed, x, reference, frame_bound)
            stretched = step(frame_placed, x, stretch)
            causes.append(cause(scale, scale_var) if drift and has else None)
            line_verdict, stretch_verdict = name(verdict, stretched, causes[-1])
            families.append(min((v for v in (line_verdict, stretch_verdict) if v is not None), key=RANK.__getitem__,
                                default=None))
        return self._far_many(columns, families, causes)


def _since_calibration(scale_ppm: float, scale_var: float, calibration) -> tuple[float, float]:
    """A line's scale since the calibration's (ppm) and its variance (ppm²)."""
    if calibration is None:
        return scale_ppm, scale_var
    return scale_ppm - calibration.scale_ppm, scale_var + calibration.covariance[2]


def _accounted(trimmer: Trimmer | None, taken: Taken) -> tuple[float, float]:
    """The image stretch the trim in force accounts for, ppm, and its σ: a print grown by g reads
    camera − grating with the scale −g and stretches its image across the pixels by the same −g (the
    pixel that saw target offset s sees s·(1 − g)); none without a trim. The stretch the tracker follows
    (``taken``: its line's value at the frame, core/stretch_follow.py) is accounted for instead while the
    trim is in force: the frames are solved with it taken out once it is significant, and the slide that
    comes with it (a lens's m × the axis's distance) is camera − grating, which the trim and its follower
    take out, flagged when behind. What the line lags is left for the watch to judge."""
    trim = trimmer.trim if trimmer is not None else None
    if trim is None:
        return 0.0, 0.0
    if math.isfinite(taken.followed_ppm):
        return taken.followed_ppm, taken.sigma_ppm
    return trim.scale_ppm, trim.scale_sigma_ppm


@dataclass(frozen=True)
class Applied:
    """What the scale watch's trim did to one frame: its position (trimmed while a trim is in force),
    the correction taken off and what the trim adds to the frame's bound (µm), and whether the watch
    blamed the frame."""

    x_mm: float = float("nan")
    trim_um: float = 0.0
    sigma_um: float = 0.0
    flagged: bool = False
    drifted: bool = False  # the line camera − grating drifted (not a single frame off it)


class Disagreement:
    """Camera − grating against the line in force (the trim's, else the calibration's), a running
    mean over the last ``SUSPECT_WINDOW`` placed frames, judged against its standard error: far
    beyond it, the positions are off. A new line (a trim applied) starts the mean again."""

    def __init__(self, monitor: ReferenceMonitor) -> None:
        self.monitor = monitor
        self._line = None
        self._known2 = 0.0  # µm²: the line's own variance at the last frame's place
        self.starting = True  # the mean's first fill against the calibration's line (:data:`START_LIMIT`)
        self.clear()

    def snapshot(self) -> tuple:
        """The running mean's state, to go back to with :meth:`restore`."""
        return self._line, self.count, self.weighted_per_um, self.precision_per_um2, self._known2, self.starting

    def restore(self, state: tuple) -> None:
        self._line, self.count, self.weighted_per_um, self.precision_per_um2, self._known2, self.starting = state

    def clear(self) -> None:
        # running means of residual/σ² and 1/σ²: their ratio weighs each frame by its bound, so that
        # frames whose bound a transient set aside widened count for as little as they know
        self.count, self.weighted_per_um, self.precision_per_um2 = 0, 0.0, 0.0

    @property
    def mean_um(self) -> float:
        return self.weighted_per_um / self.precision_per_um2 if self.precision_per_um2 > 0 else 0.0

    def add(self, x_mm: float, reference_mm: float, bound_mm: float, scatter: float | None = None) -> bool:
        """One frame (skipped unless all three are finite); True while the mean disagreement is beyond its limit.
        ``scatter``: the monitor's scatter before the frame, when the monitor has since taken more frames."""
        monitor = self.monitor
        if math.isfinite(x_mm) and math.isfinite(reference_mm) and math.isfinite(bound_mm) and bound_mm > 0:
            line = monitor.baseline or monitor.calibration
            if line is not self._line:
                self.starting = self.starting and self._line is None  # a trim's line: the mean slides on it
                self._line = line
                self.clear()
            expected = known2 = 0.0
            if line is not None:  # the line's value and variance here, in scalars: this runs on every frame
                d = (reference_mm - line.center_mm) * 1e-3  # ppm·mm → µm
                var_o, cov, var_s = line.covariance
                expected, known2 = line.offset_um + line.scale_ppm * d, max(var_o + 2.0 * d * cov + d * d * var_s, 0.0)
            if monitor.structure is not None:  # the model's own error at this place, as the monitor takes it out
                x_mm = x_mm - monitor.structure.at_one_um(reference_mm) * 1e-3
            residual = (x_mm - reference_mm) * 1e3 - expected
            variance = (bound_mm * 1e3) ** 2 + (monitor.reference_sigma_mm * 1e3) ** 2
            residual, beyond = self._gated(residual, variance, monitor.scatter if scatter is None else scatter)
            self.count = min(self.count + 1, SUSPECT_WINDOW)
            self.starting = self.starting and self.count < SUSPECT_WINDOW
            self.weighted_per_um += (residual / variance - self.weighted_per_um) / self.count
            self.precision_per_um2 += (1.0 / variance - self.precision_per_um2) / self.count
            self._known2 = known2
            if beyond:
                return True
        return self._far()

    def _gated(self, residual_um: float, variance_um2: float, scatter: float) -> tuple[float, bool]:
        """(the frame's residual as the mean takes it, whether it was beyond the gate). Beyond
        :data:`GATE` of its σ from the running mean (the monitor's scatter), the frame is off the
        grating and says so, and it enters the mean clipped to the gate: a single grating reading
        0.5 mm off had held the mean beyond its limit, and every frame flagged, for the next 20
        frames; clipped, it moves the mean a third of its limit. An episode that stays beyond moves
        it a gate's worth a frame, each of its frames flagged on its own."""
        if self.count == 0:
            return residual_um, False
        deviation = residual_um - self.mean_um
        gate2 = GATE * GATE * (variance_um2 * scatter + 1.0 / (self.count * self.precision_per_um2))
        if deviation * deviation <= gate2:
            return residual_um, False
        return self.mean_um + (math.sqrt(gate2) if deviation > 0 else -math.sqrt(gate2)), True

    def add_many(self, x_mm: np.ndarray, reference_mm: np.ndarray, bound_mm: np.ndarray,
                 scatter: np.ndarray) -> np.ndarray:
        """:meth:`add` of each frame in order (``scatter``: the monitor's before each frame): whether
        the mean is beyond its limit after each."""
        far = np.zeros(len(x_mm), dtype=bool)
        monitor = self.monitor
        line = monitor.baseline or monitor.calibration
        fresh = self.count == 0 and self.weighted_per_um == 0.0 and self.precision_per_um2 == 0.0
        if not _kernels.COMPILED or (line is not self._line and not fresh):  # a new line mid-chunk: as add does
            rows = zip(x_mm.tolist(), reference_mm.tolist(), bound_mm.tolist(), scatter.tolist())
            for k, (x, reference, bound, before) in enumerate(rows):
                far[k] = self.add(x, reference, bound, before)
            return far
        valid = np.isfinite(x_mm) & np.isfinite(reference_mm) & np.isfinite(bound_mm) & (bound_mm > 0)
        if line is not self._line and valid.any():  # the first line of an empty mean: add's switch, taken first
            self.starting, self._line = self.starting and self._line is None, line
        # what add squares and interpolates, in Python's own arithmetic (``**`` is libm's pow, not a product)
        bound2 = np.zeros(len(x_mm))
        at = np.flatnonzero(valid)
        bound2[at] = [(bound * 1e3) ** 2 for bound in bound_mm[at].tolist()]
        structure = np.zeros(len(x_mm))
        if monitor.structure is not None:
            structure[at] = [monitor.structure.at_one_um(reference) for reference in reference_mm[at].tolist()]
        state = np.array([self.count, self.starting, self.weighted_per_um, self.precision_per_um2, self._known2],
                         dtype=np.float64)
        noise = monitor.structure.noise_um if monitor.structure is not None else 0.0
        p = np.array([line is not None, *((line.offset_um, line.scale_ppm, line.center_mm, *line.covariance)
                                          if line is not None else (0.0,) * 6),
                      SUSPECT_WINDOW, GATE * GATE, monitor.calibration_structure_um ** 2,
                      (monitor.reference_sigma_mm * 1e3) ** 2, noise ** 2,
                      max(monitor.floor_um, 0.5 * monitor.resolution_mm * 1e3), START_LIMIT, SUSPECT_LIMIT],
                     dtype=np.float64)
        _kernels._disagreement_run(state, p, np.ascontiguousarray(x_mm, dtype=np.float64),
                                   np.ascontiguousarray(reference_mm, dtype=np.float64), bound2, structure,
                                   np.ascontiguousarray(scatter, dtype=np.float64), valid, far)
        count, starting, self.weighted_per_um, self.precision_per_um2, self._known2 = state.tolist()
        self.count, self.starting = int(count), bool(starting)
        return far

    def _far(self) -> bool:
        monitor = self.monitor
        if self.count == 0:
            return False
        # The mean's noise (the frames averaged so far, at most the window's worth) and what no
        # averaging removes. Judged from the first frame on: a run that starts 20-40 bounds off the
        # grating (a print grown, a camera moved, a sensor's response changed since calibration)
        # would have its first 5-15 frames called fresh while the window fills.
        # the correction's, fixed per place
        noise = monitor.structure.noise_um if monitor.structure is not None else 0.0
        sigma2 = 1.0 / (self.count * self.precision_per_um2) + self._known2 + monitor.calibration_structure_um ** 2 \
            + (monitor.reference_sigma_mm * 1e3) ** 2 + noise ** 2
        floor = max(monitor.floor_um, 0.5 * monitor.resolution_mm * 1e3)
        limit = START_LIMIT if self.starting else SUSPECT_LIMIT
        return abs(self.mean_um) > max(limit * math.sqrt(sigma2), floor)


def make(tracker) -> "ScaleWatch | None":
    """The tracker's scale watch (an owner with a trim hands its own in: ``monitor_for(..., watches=)``);
    none for a model already off its bound on its own calibration (the adequacy watch has it)."""
    if not scale_tells(tracker.model):
        return None
    return ScaleWatch.for_model(tracker.model)
