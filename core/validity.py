"""Is the model still the right one? Watches that look past χ², each naming a family of causes.

χ² alone is blind when a per-frame nuisance absorbs a change: a light field solved across the
line can mimic a blur, a robust solve can hide a growing defect. So besides the running χ², the
monitor watches what the nuisances cost and how far they moved (the frame's bound against the
calibration's, the light gain, a focus term, the pixels set aside, transients, the camera against
the grating). Each watch answers in its own family, so a stale flag always comes with a reason a
person can act on: ``light``, ``focus``, ``pixels``, ``transients``, ``magnification``, ``scale`` or
``geometry``.

A watch is one small class with ``observe(sign) -> family | None`` in a module of
``core/watches/`` that defines ``make(tracker) -> Watch | None``: the monitor finds them by name,
so a new watch is one module. Every frame the monitor asks each watch; the model is stale while
any of them blames a family, with the first such family (in the order of :data:`FAMILIES`, from
the most to the least specific cause) as its reason.
"""

from __future__ import annotations

import importlib
import math
import pkgutil
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, Sequence

FAMILIES = ("transients", "pixels", "light", "focus", "magnification", "scale", "geometry", "period", "texture")
RANK = {family: rank for rank, family in enumerate(FAMILIES)}

# What to do about each family of causes, one line each (the CLI, the daemon's events and page).
ADVICE = {
    "transients": "glints or passing dust keep hitting the line: shade the target or move the ROI",
    "texture": "marks learned on the print (dust, a smudge) move the position away from where the print alone "
               "places it: learned from positions something pulled (read the grating while they are learned), or the "
               "print changed under them",
    "pixels": "pixels went bad since calibration: recalibrate (the new calibration masks them)",
    "light": "the light changed beyond what the model can follow at its precision: fix the light or recalibrate",
    "focus": "the focus moved since calibration: check the lens and its mount, then recalibrate",
    "magnification": "the image stretches across the pixels since calibration: the lens's magnification moved "
                     "(warming up; the image slides with it unless the optical axis is on the ROI) or the print "
                     "itself grew: let the lens reach its temperature, track with the grating and --trim, or "
                     "recalibrate",
    "scale": "camera and grating disagree beyond their bounds: far off (a hundred bounds and more), the model's "
             "period or pitch does not match this rig (a model of another target or lens); drifting apart, the "
             "target's scale (paper growth, temperature), the camera's place on the stage, or the grating read at "
             "another instant than the exposure (its latency shows as an offset that follows the speed): recalibrate",
    "geometry": "the images are no longer what the model describes (the model's period or pitch does not match "
                "this rig, the camera moved, the print changed): recalibrate (graytrack diagnose names the cause)",
    "period": "acquired without a grating, another period of the print fits as well and the model places it "
              "elsewhere than a whole period away: the position waits for the frames to tell them apart; read the "
              "grating, or start the run where the stroke holds one period",
}


@dataclass(slots=True)
class FrameSign:
    """What one frame's solve tells the monitor beyond its position (NaN/None: not known). A field
    named in core/frame_record.py is the quantity declared there, under the same name in
    :class:`~graytrack.core.solvers.FrameSolution`, whence it is copied."""

    frame: int
    chi2: float = float("nan")
    information: float = float("nan")  # the frame's Fisher information on x (1/mm²), as solved
    information_calibrated: float = float("nan")  # the same at x with the calibrated light and all samples
    gain: float = 1.0
    offset_gray: float = 0.0
    focus: float = 0.0  # change in blur variance since calibration (px²), when a focus term was solved
    focus_sigma: float = float("nan")  # its standard error
    rejected_px: int = 0
    transient_px: int = 0
    transient_at: float = float("nan")  # mean pixel (column) of those samples: a blob that stays put is no transient
    x_mm: float = float("nan")
    reference_mm: float = float("nan")  # the grating at the same instant, when read
    placed: bool = True
    rows_averaged: int = 1  # raw rows behind each model row (information scales with it)
    free_light: bool = False  # the light's gain and offset were solved with x
    field: bool = False  # a light field across the line was solved with x
    chi2_average: float = float("nan")  # the tracker's running χ² (its light control reads it too)
    chi2_suspect: bool = False  # the running χ² is beyond its own spread above calibration's level
    chi2_stale: bool = False  # ... and beyond the stale limit
    # What the frame's residual looks like, computed only when a watch asks (it costs an evaluation):
    # the share of its excess χ² each family's shapes explain (see core/watches/attribution.py).
    explain: Callable[[], dict[str, Any]] | None = None
    # The frame's stretch across the pixels (m, its σ: core/stretch.py), computed when a watch asks.
    stretch: Callable[[], tuple[float, float]] | None = None
    moving: bool = False  # the answer followed a light feature moving across the field (core/moving_band.py)
    period_guess: bool = False  # without a grating, another period of the print fits as well (core/period_rival.py)
    pulled: bool = False  # the print's learned marks moved the answer from the print's own (core/texture.py)


SIGN_FIELDS = tuple(FrameSign.__slots__)


class Watch(Protocol):
    """One look at the model's validity; keeps its own running state.

    A watch may also name the fields of :class:`FrameSign` it reads (``reads``) and take them as
    arguments of ``step``: the monitor then feeds it many frames from columns without building a
    sign per frame (:meth:`Monitor.observe_many`, batch tracking); ``observe(sign)`` is ``step``
    on one sign's fields, so both give the same verdicts. A watch may also take a whole chunk of
    frames at once, ``step_many(columns, n) -> list of families`` (``columns`` a :class:`Columns`,
    numpy arrays on request; core/watches/_kernels.py holds compiled loops), returning None for
    frames it leaves to ``step``: it must give what ``step`` gives frame by frame, state included
    (tests/core/test_watch_kernels.py holds each watch to that)."""

    family: str
    # Optional, read with getattr (so not a protocol member: most watches leave it out): ``decisive =
    # True``, a verdict on the model itself (refused or inadequate at calibration) outranks whatever a
    # frame's nuisances suggest: those only describe how a wrong model fails on this frame.

    def observe(self, sign: FrameSign) -> str | None:
        """The family this watch blames now (None: nothing to say)."""


class Decisive(str):
    """A family named decisively on this frame alone, by a watch that is not decisive on every frame: the
    scale watch carries the far-off judgement (core/watches/far_off.py), decisive for the model's scale, and
    names it ``magnification`` where the line's drift is a lens's (core/watches/scale.py). It outranks what
    a frame's nuisances suggest, as a decisive watch's verdict does, but not a watch decisive on every frame
    (the model's own calibration refused it: those said more than the far-off ever did, being asked after
    it). The monitor reports it as the plain family."""

    __slots__ = ()


@dataclass
class Verdict:
    stale: bool = False
    reason: str | None = None


@dataclass
class Monitor:
    """Every watch, asked once per frame; the verdict is stale while any watch blames a family."""

    watches: list[Watch] = field(default_factory=list)
    verdict: Verdict = field(default_factory=Verdict)

    def observe(self, sign: FrameSign) -> Verdict:
        reason, rank = None, len(FAMILIES)
        for watch in self.watches:  # every watch, every frame: each keeps its own running state
            family = watch.observe(sign)
            if family is not None:
                reason, rank = _ranked(family, getattr(watch, "decisive", False), reason, rank)
        if reason != self.verdict.reason:
            self.verdict = Verdict(reason is not None, reason)
        return self.verdict

    def observe_many(self, columns: dict[str, list]) -> list[str | None]:
        """:meth:`observe` of consecutive frames given as columns (one list per field of
        :class:`FrameSign`, all of one length): each watch takes all of them in turn (its state
        runs frame by frame as in :meth:`observe`; the watches share none), then each frame's
        reason is chosen as :meth:`observe` chooses it. Returns the reason of every frame (None:
        not stale); the verdict is left at the last frame's."""
        n = len(columns["frame"])
        columns = columns if isinstance(columns, Columns) else Columns(columns)
        reasons: list[str | None] = [None] * n
        ranks = [len(FAMILIES)] * n
        for watch in self.watches:
            families = _observe_all(watch, columns, n)
            if not any(families):
                continue
            decisive = getattr(watch, "decisive", False)
            for i, family in enumerate(families):
                if family is not None:
                    reasons[i], ranks[i] = _ranked(family, decisive, reasons[i], ranks[i])
        if n and reasons[-1] != self.verdict.reason:
            self.verdict = Verdict(reasons[-1] is not None, reasons[-1])
        return reasons


DECISIVE, MARKED = -2, -1  # the ranks of a decisive watch's verdict and of one marked :class:`Decisive`


def _ranked(family: str, decisive: bool, reason: str | None, rank: int) -> tuple[str | None, int]:
    """The frame's (reason, rank) once a watch named ``family``: a decisive watch's verdict outranks
    everything before it (the last decisive watch asked has the say), a :class:`Decisive` verdict
    everything but a decisive watch's, any other the less specific families (:data:`FAMILIES`)."""
    if decisive:
        return family, DECISIVE
    if type(family) is Decisive:
        return (str(family), MARKED) if rank > DECISIVE else (reason, rank)
    return (family, RANK[family]) if RANK[family] < rank else (reason, rank)


class Columns(dict):
    """Frames' signs as columns (one list per field of :class:`FrameSign`), each also as a numpy
    array once a watch asks for it (:meth:`array`), made once for every watch that reads it."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._arrays: dict[str, Any] = {}

    def array(self, name: str, dtype: Any = None) -> Any:
        import numpy as np

        key = f"{name}:{dtype}"
        value = self._arrays.get(key)
        if value is None:
            value = self._arrays[key] = np.asarray(self[name], dtype=dtype)
        return value


def _observe_all(watch: Watch, columns: dict[str, list], n: int) -> list[str | None]:
    """One watch over ``n`` frames of columns: by its ``step_many`` when it has one and takes
    these frames at once (returns None when it does not), else by its ``step`` on the fields it
    reads, else sign by sign. ``step_many`` gives what ``step`` gives frame by frame."""
    many = getattr(watch, "step_many", None)
    if many is not None and n:
        if not isinstance(columns, Columns):
            columns = Columns(columns)
        families = many(columns, n)
        if families is not None:
            return families
    reads = getattr(watch, "reads", None)
    if reads is None:
        return [watch.observe(FrameSign(**dict(zip(SIGN_FIELDS, row))))
                for row in zip(*(columns[name] for name in SIGN_FIELDS))]
    step = watch.step  # type: ignore[attr-defined]  # a watch naming ``reads`` has ``step`` (Watch)
    if not reads:
        return [step() for _ in range(n)]
    return [step(*row) for row in zip(*(columns[name] for name in reads))]


def monitor_for(tracker: Any, watches: Sequence[Watch] = ()) -> Monitor:
    """A monitor with every watch of ``core/watches/`` that applies to ``tracker``'s model; a watch
    handed in (``watches``: its owner's, e.g. the scale watch that carries the daemon's trim) takes
    the place of the one its module would make, so a frame is judged once, by the watch in force."""
    from graytrack.core import watches as found  # the watches read the tracker's model: imported on use

    given = {type(watch).__module__: watch for watch in watches}
    replaced = {name for watch in watches for name in getattr(watch, "replaces", ())}  # a watch carrying another's
    made = []
    for info in pkgutil.iter_modules(found.__path__):
        if info.name.startswith("_") or f"{found.__name__}.{info.name}" in replaced:
            continue
        name = f"{found.__name__}.{info.name}"
        if name in given:
            made.append(given.pop(name))
            continue
        make = getattr(importlib.import_module(name), "make", None)
        if make is not None and (watch := make(tracker)) is not None:
            made.append(watch)
    # a watch made here may carry another's too (the scale watch carries the magnification watch): the one
    # its module made is not asked again (one handed in is: its owner reads it)
    handed = {id(watch) for watch in watches}
    carried = {name for watch in made for name in getattr(watch, "replaces", ())}
    kept = [watch for watch in made if id(watch) in handed or type(watch).__module__ not in carried]
    return Monitor(kept + list(given.values()))


def running(average: float | None, value: float, window: int) -> float:
    """An exponential average over about ``window`` samples (the first value starts it)."""
    if average is None or not math.isfinite(average):
        return value
    return average + (value - average) / window
