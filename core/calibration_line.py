"""The line camera − grating on the calibration's own run, kept in the model: what drift is
measured from while tracking (core/reference_monitor.py, core/watches/scale.py).

A calibration-time step, apart from the monitor so that the monitor, which tracking uses, does
not import tracking."""

from __future__ import annotations

import math

import numpy as np

from graytrack.core.adequacy import error_profile
from graytrack.core.chi2_curve import frame_spread, measured as measured_chi2_curve
from graytrack.core.noise import reference_resolution_mm
from graytrack.core.reference_monitor import MIN_FRAMES, Line, ReferenceMonitor, structure_profile, structure_um
from graytrack.core.timing import model_reference
from graytrack.core.tracking import Tracker, track
from graytrack.core.watches.magnification import MagnificationWatch, StretchProfile


def record_calibration_line(model, recording) -> Line | None:
    """Track the calibration ``recording`` with the ``model`` fitted to it, as tracking will, and keep
    the line camera − grating in ``model.info["reference_line"]``: the agreement drift is measured
    from; and how far off the line its frames are, stretch by stretch along the stroke, against their
    bound (``calibration_error_profile``: where the model cannot measure at its bound). None (and nothing kept) when
    the recording has no grating reading or too few frames."""
    # the grating at the exposure: a latch the calibration found is no error of the model's
    reference = model_reference(model, recording.t, recording.reference)
    if np.isfinite(reference).sum() < MIN_FRAMES:
        return None
    own = MagnificationWatch(model.period_mm, record=True)  # the model's own stretch along the stroke
    # the focus is the model's by construction: estimates that move along the stroke are its own
    # residue there, not a blur (core/focus_follow.py), and the frames are tracked as before
    tracker = Tracker(model, light="auto", robust=True, follow_focus=False)
    result = track(model, recording, reference=reference, tracker=tracker, watches=[own])
    stretch = StretchProfile.measured(own.record or [])
    if stretch is not None:
        model.info["stretch_profile"] = stretch.as_dict()
    else:
        model.info.pop("stretch_profile", None)
    # the χ² level along the stroke, as tracking will see it: what a run's χ² is held against (core/chi2_curve.py)
    curve = measured_chi2_curve(result.x_mm[result.locked], result.chi2[result.locked]) \
        if result.chi2 is not None else None
    if curve is not None:
        model.info["calibration_chi2_curve"] = curve.as_dict()
    else:
        model.info.pop("calibration_chi2_curve", None)
    # ... and how widely one frame's χ² scatters about that level against white noise in as many samples: noise
    # the samples share (a row's offset drawn each frame, a pixel flickering between two levels) scatters it as
    # fewer samples' would (core/chi2_curve.py frame_spread)
    if result.chi2 is not None:
        model.info["frame_chi2_spread"] = round(
            frame_spread(result.x_mm[result.locked], result.chi2[result.locked], curve,
                         model.n_rows * model.n_pixels * float(np.mean(model.seen()))), 3)
    step = float(recording.meta.get("grating_resolution_mm", 0.0) or 0.0) or reference_resolution_mm(reference)
    lo, hi = model.stroke_range_mm
    monitor = ReferenceMonitor(0.5 * (lo + hi), 0.5 * (hi - lo), window=max(reference.size, MIN_FRAMES),
                               reference_sigma_mm=step / math.sqrt(12.0), resolution_mm=step)
    for x, ref, bound, locked in zip(result.x_mm.tolist(), reference.tolist(), result.crlb_mm.tolist(),
                                     result.locked.tolist()):
        if locked:
            monitor.observe(x, ref, bound)
    if monitor.frames >= MIN_FRAMES:
        monitor._update()  # the fit of every frame (observe fits every few)
    line = monitor.estimate
    if line is not None:
        model.info["reference_line"] = line.as_dict()
        usable = result.locked & np.isfinite(result.x_mm) & np.isfinite(reference)
        off_line_um = (result.x_mm[usable] - reference[usable]) * 1e3 - line.at_um(reference[usable])
        model.info["reference_structure_um"] = round(structure_um(reference[usable], off_line_um,
                                                                  result.crlb_mm[usable] * 1e3), 4)
        # ... and where along the stroke it is, to take out of a run's camera − grating (fixed in position)
        profile = structure_profile(reference[usable], off_line_um, result.crlb_mm[usable] * 1e3)
        if profile is not None:
            model.info["reference_structure_profile"] = profile.as_dict()
        else:
            model.info.pop("reference_structure_profile", None)
        # At a place the model was not fitted to, its coefficients' noise leaves an error of about the
        # bound × √(coefficients / frames), fixed there: what the in-sample structure above cannot
        # see (the model was fitted to these very frames) and a stage parked for long measures.
        mean_bound2_um2 = float(np.mean(np.square(result.crlb_mm[usable] * 1e3)))
        model.info["reference_place_sigma_um"] = round(
            math.sqrt(mean_bound2_um2 * model.n_coeffs / max(int(usable.sum()), 1)), 4)
        # the error about its mean, as a run's error is judged: a line would take in part of a model's error
        # that is no line (a scratch's stretch), and hide it
        error_mm = result.x_mm[usable] - reference[usable]
        bound2 = result.crlb_mm[usable] ** 2 + monitor.reference_sigma_mm**2  # the grating's rounding is in the error
        model.info["calibration_error_profile"] = error_profile(reference[usable], error_mm - error_mm.mean(), bound2)
    return line
