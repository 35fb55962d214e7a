"""A run tracked as `graytrack track` does, scored against the virtual rig's truth (not the grating).

The benches that judge "never silently wrong" share this: the grating is one more instrument with
its own read-out step and latch, so a frame is judged against where the stage truly was. Modes are
those of the command: the grating read (the default), ``--trim`` (positions trimmed against it as
the daemon's online trim would) and ``--no-reference`` (a rig whose grating is not read while
running: the origin is then known only up to whole periods, which the score takes out).

    from truth_score import MODES, scored      # run from bench/ (a script's own folder is on the path)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graytrack.core.slide import carry
from graytrack.service.commands.track import estimated, slide_for, solve
from graytrack.service.commands.track_scale import check

FAR_PULL = 4.0  # a placed frame this many of its own bounds off the truth is wrong, not noise's tail (6e-5)
MODES = {"grating": dict(trim=False, no_reference=False), "--trim": dict(trim=True, no_reference=False),
         "--no-reference": dict(trim=False, no_reference=True)}


@dataclass(frozen=True)
class Score:
    """One tracked run against the truth; shares are of the run's frames (``silent``: of the placed ones)."""

    frames: int
    placed: int
    lost: int  # frames not placed, repeated images (set aside by design) not counted
    repeated: int
    std_um: float  # error spread against the truth
    rms_um: float  # error rms against the truth (a bias counts)
    bound_um: float  # rms of the frames' noise floors (with the trim's share under --trim; the slide's is in "far")
    flagged: int  # stale by the model's χ² or by the camera against the grating
    far: int  # placed frames beyond FAR_PULL of their bounds off the truth
    silent: int  # ... of them not flagged
    marks: int  # print texture learned (core/texture.py)
    focus: int  # frames whose focus term was on (an estimate shown: core/focus_follow.py)
    trimmed: int  # frames a trim was in force on
    stretched: int = 0  # frames solved with the lens's stretch taken out (core/stretch_follow.py, under --trim)
    placed_frames: tuple[int, ...] | None = None  # which frames were placed (None: not kept)

    @property
    def ratio(self) -> float:
        return self.std_um / self.bound_um

    @property
    def silent_share(self) -> float:
        return self.silent / max(self.placed, 1)

    @property
    def learned(self) -> str:
        """What the run learned or took on, "-" for nothing (what a steady run must show)."""
        parts = [f"{count} {what}" for count, what in ((self.marks, "marks"), (self.focus, "focus frames"),
                                                       (self.trimmed, "trimmed"), (self.stretched, "stretched"))
                 if count]
        return ", ".join(parts) or "-"

    def cell(self) -> str:
        return (f"{self.ratio:5.2f}x (rms {self.rms_um / self.bound_um:5.2f}x) lost {self.lost:3d} "
                f"flagged {100 * self.flagged / self.frames:5.1f} % far {self.far:3d} unflagged {self.silent:3d} "
                f"({100 * self.silent_share:4.2f} %) learned {self.learned}")


def scored(model, run, truth, trim: bool = False, no_reference: bool = False, engine: str = "watches") -> Score:
    """``run`` tracked as `graytrack track [--trim] [--no-reference] [--engine E]` does (light auto, robust, the
    print's texture learned, the tracker's scale watch), each frame against ``truth``."""
    if engine == "estimator":
        return estimator_scored(model, run, truth, trim, no_reference)
    slide = slide_for(run, model, no_reference)  # without a grating each bound carries the slide, as track's
    result, _, watch = solve(run, model, no_reference=no_reference, trim=trim, slide=slide, note=lambda line: None)
    scale = check(run, model, result, trim, watch).columns
    error = (result.x_mm - truth.x_mm) * 1e3
    if no_reference:  # acquired on the image alone: its origin is known up to whole periods
        period_um = model.period_mm * 1e3
        error -= period_um * np.round(np.nanmedian(error) / period_um)
    floor = result.crlb_mm * 1e3  # the noise floor: what the ratio is stated against
    if result.slide_sigma_um is None:
        carry(result, slide)
    bound = result.crlb_mm * 1e3  # the bound track reports (the slide's σ in it): what "far" is judged by
    placed = np.isfinite(error)
    repeated = result.repeated if result.repeated is not None else np.zeros(placed.size, dtype=bool)
    flagged = result.stale | (scale["scale_stale"] == 1)
    far = placed & (np.abs(error) > FAR_PULL * bound)
    trimmed = np.isfinite(scale["trim_um"]) & (scale["trim_um"] != 0)
    focus = np.isfinite(result.focus_px2) if result.focus_px2 is not None else np.zeros(placed.size, dtype=bool)
    return Score(frames=int(placed.size), placed=int(placed.sum()), lost=int((~placed & ~repeated).sum()),
                 repeated=int(repeated.sum()), std_um=float(np.nanstd(error)),
                 rms_um=float(np.sqrt(np.nanmean(error ** 2))), bound_um=float(np.sqrt(np.nanmean(floor ** 2))),
                 flagged=int(flagged.sum()), far=int(far.sum()), silent=int((far & ~flagged).sum()),
                 marks=int((result.texture or {}).get("learned", 0)), focus=int(focus.sum()),
                 trimmed=int(trimmed.sum()),
                 stretched=watch.stretch_follow.corrected_frames if watch is not None and watch.stretch_follow else 0,
                 placed_frames=tuple(np.flatnonzero(placed).tolist()))


def estimator_scored(model, run, truth, trim: bool = False, no_reference: bool = False) -> Score:
    """The same score for `graytrack track --engine estimator`: its bound is the posterior σ with every
    nuisance (what "far" is judged by), its floor each frame's own noise floor (what the ratio is stated
    against); what it learned is the jumps it took and the frames whose blur it showed."""
    result, _ = estimated(run, model, no_reference=no_reference, trim=trim)
    error = (result.x_mm - truth.x_mm) * 1e3
    if no_reference:
        period_um = model.period_mm * 1e3
        error -= period_um * np.round(np.nanmedian(error) / period_um)
    bound = result.crlb_mm * 1e3
    placed = np.isfinite(error)
    far = placed & (np.abs(error) > FAR_PULL * bound)
    flagged = result.stale
    focus = np.isfinite(result.focus_px2)
    repeated = result.repeated
    return Score(frames=int(placed.size), placed=int(placed.sum()), lost=int((~placed & ~repeated).sum()),
                 repeated=int(repeated.sum()),
                 std_um=float(np.nanstd(error)), rms_um=float(np.sqrt(np.nanmean(error ** 2))),
                 bound_um=float(np.sqrt(np.nanmean(bound ** 2))), flagged=int(flagged.sum()), far=int(far.sum()),
                 silent=int((far & ~flagged).sum()), marks=0, focus=int(focus.sum()), trimmed=0)
