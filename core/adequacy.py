"""How far a calibrated model's own residual moves the positions it gives, against their bound.

A model that leaves structure in its calibration residual (a print harmonic it lacks, a light it
does not describe) places frames off by the part of that residual that looks like a shift: per
frame, the weighted projection of the residual onto ∂F/∂x, with the light's gain and offset
profiled out as the tracker does. Its rms over the calibration frames, against the rms of their
Cramér–Rao bounds, says before any run whether the model can measure at its bound at all: a
model 5× off on the very frames it was fitted to will be at least as far off on the next run,
however still its χ² stays, and every one of its positions must say so.
"""

from __future__ import annotations

import math

import numpy as np

from graytrack.core.calibration_data import CalibrationData
from graytrack.core.chi2_curve import frame_spread
from graytrack.core.compression import bound_factor, find_jpeg, judged_factor
from graytrack.core.light_level import stated_level
from graytrack.core.light_return import replay
from graytrack.core.models.fourier import FourierModel
from graytrack.core.replay import frame_weights, picked_frames, replayed_frames
from graytrack.core.stream_focus import stream_focus_factor

INADEQUATE_RATIO = 2.0  # beyond this, every position the model gives is flagged (core/watches/adequacy.py)
# frames of a running χ² mean whose spread a stream's is measured on (the tracker's FIELD_WINDOW: its blur suspicion)
SPREAD_WINDOW = 20
ROW_SIGNIFICANCE = 3.0  # standard errors by which the rows' offsets must stand out of their noise to be kept: below,
# no banding is the better guess (a strip's solve then spends nothing on it)
ROW_LEVEL_SHARE = 0.95  # the χ² level with the rows' offsets taken out, over the level with them, below which they are
# taken out of every frame: offsets that carry less of the residual move a frame's solve by less than its noise (a
# JPEG stream's blocks leave a few hundredths of a gray a row)
FRAME_GAIN_RATE = "frame_gain_rate"  # the model's info key: how fast the gain walks from frame to frame (1/√s)
LIGHT_PROFILE = "light_profile"  # ... and the light's gain along the stroke (light_profile)
PROFILE_FRAMES = 25  # calibration frames per stretch of the stroke in the local error profile (its ratio to ~15 %)


def error_ratio(errors: tuple[np.ndarray, np.ndarray, np.ndarray] | None) -> float:
    """rms of the per-frame position bias the residual implies over the rms of the frames' bounds
    (``errors``: :func:`frame_errors`)."""
    return float("nan") if errors is None else float(np.sqrt(np.mean(errors[1] ** 2) / np.mean(errors[2])))


def error_profile(x_mm: np.ndarray, error_mm: np.ndarray, bound2_mm2: np.ndarray) -> dict[str, list[float]] | None:
    """The error fixed along the stroke over the bound, stretch by stretch (equal numbers of frames,
    :data:`PROFILE_FRAMES` each): ``{"edges_mm": [B + 1], "ratio": [B]}``; None for too few frames.
    A stretch's ratio is √((R + b²) / b²): R its frames' :func:`shared_error` power, b² their mean
    bound², as the rms error over the rms bound reads for a frame there with its noise at its bound.

    A model can be at its bound over most of the stroke and far off where the print has what it
    lacks (a scratch the Fourier terms cannot follow): a ratio over the whole stroke averages that
    away, the frames there are wrong all the same, and on every run (core/watches/adequacy.py
    flags them). The calibration's own frames tracked as tracking will are what to measure it on
    (core/calibration_line.py): their errors come out as a run's do. Only the error that repeats
    at the place is the place's: a frame off on its own (a row-banded frame taken for a shadow's
    band: 15 bounds; a pixel's flip) errs at that instant, not there, and a run passes the place at
    other instants. The rms counted it: the steady 16-row strip with row banding and telegraph
    pixels had 26 of 500 frames flagged `geometry`, on two stretches of 25 frames at 2.4x and 4.9x,
    each for one frame 8 and 15 bounds off (1.4x at most now). A scratch's stretches, off on every
    frame there, still are flagged (6 of the 7 beyond the limit, 2.3-3.5x)."""
    if x_mm.size < 2 * PROFILE_FRAMES:
        return None
    order = np.argsort(x_mm)
    x, error, bound2 = x_mm[order], error_mm[order], bound2_mm2[order]
    shared = shared_error(error)
    stretches = np.array_split(np.arange(x.size), x.size // PROFILE_FRAMES)
    ratio = [float(np.sqrt(max(1.0 + np.mean(shared[s]) / np.mean(bound2[s]), 0.0))) for s in stretches]
    # each stretch reaches half-way to its neighbours' frames; the ends, the calibrated stroke's
    inner = [0.5 * (x[s[-1]] + x[t[0]]) for s, t in zip(stretches[:-1], stretches[1:])]
    edges = [float(x[0])] + [float(v) for v in inner] + [float(x[-1])]
    return {"edges_mm": [round(v, 6) for v in edges], "ratio": [round(v, 3) for v in ratio]}


def shared_error(error: np.ndarray) -> np.ndarray:
    """Each frame's error times the mean of its neighbours' along the stroke (``error``: two or more,
    in the order of place): the power of the error fixed there. Frames next to each other see the same print a
    fraction of a pixel apart (a sweep's consecutive frames, or another pass's), so an error fixed
    on the print or the stroke they share, and the product keeps its square; errors that do not
    repeat (the noise, a flip, a one-frame misstep) are independent, and their products average to
    zero, a lone frame's counting as far as its neighbours' errors go (linearly, not squared)."""
    before = np.concatenate((error[1:2], error[:-1]))  # at the ends, the one neighbour twice
    after = np.concatenate((error[1:], error[-2:-1]))
    return error * 0.5 * (before + after)


def frame_errors(model: FourierModel, data: CalibrationData) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(x mm, position bias mm, bound² mm²) of the calibration frames looked at (up to
    core/replay.py ``MAX_FRAMES``, evenly spread) that the model can place; None when it places none."""
    data = picked_frames(data)
    x = data.x_mm
    frames = model.prepare(data.frames).reshape(x.size, -1)
    values, slopes = model.predict(x, with_derivative=True)
    values, slopes = values.reshape(x.size, -1), slopes.reshape(x.size, -1)
    weights = frame_weights(model, data, values)
    # per frame: regress the residual on [F′, F, 1] (x, gain, offset) by weighted least squares
    basis = np.stack([slopes, values, np.ones_like(values)], axis=2)  # (K, P, 3)
    fisher = np.einsum("kp,kpi,kpj->kij", weights, basis, basis)
    residual = frames - values
    score = np.einsum("kp,kpi,kp->ki", weights, basis, residual)
    usable = np.linalg.det(fisher) > 0
    if not usable.any():
        return None
    fisher, score, weights, residual, slopes = fisher[usable], score[usable], weights[usable], residual[usable], \
        slopes[usable]
    x = x[usable]
    step = free_score(fisher, score)
    free_shift = step[:, 0]
    free_bound2 = np.linalg.inv(fisher)[:, 0, 0]  # x with the gain and offset profiled out
    # As the tracker solves a frame (Tracker.solve): the light held at calibration unless the model
    # has a per-frame common mode, or the frame's χ² with the light held asks for it, or the frames
    # before left it free (core/light_return.py, replayed over these frames in order). A per-frame
    # offset too small to ask then moves a held frame's position, and must count here.
    held_shift = score[:, 0] / fisher[:, 0, 0]
    held_residual = residual - held_shift[:, None] * slopes
    chi2 = np.einsum("kp,kp->k", weights, held_residual**2) / np.maximum((weights > 0).sum(axis=1), 1)
    calibration_chi2 = float(model.info.get("calibration_chi2") or 1.0)
    limit = calibration_chi2 * (1.0 + 5.0 * np.sqrt(2.0 / (model.n_rows * model.n_pixels)))
    gained = np.einsum("ki,ki->k", score, step) - score[:, 0] ** 2 / fisher[:, 0, 0]  # χ² the free light gains
    free = np.full(chi2.shape, True) if model.common_mode else replay(chi2 > limit, gained)
    shift = np.where(free, free_shift, held_shift)
    bound2 = np.where(free, free_bound2, 1.0 / fisher[:, 0, 0])
    return x, shift, bound2


def free_score(fisher: np.ndarray, score: np.ndarray) -> np.ndarray:
    """``(K, 3)``: each frame's least-squares step in (x, gain, offset)."""
    return np.linalg.solve(fisher, score[..., None])[..., 0]


def inadequacy(info: dict) -> str | None:
    """``geometry`` when a model places its own calibration frames beyond :data:`INADEQUATE_RATIO`
    times their bound (the images are not what it describes), else None.

    The bound is the one its frames allow: for a JPEG stream, the sensor's widened by the
    quantisation (``info["stream"]``). Such a stream measured at that bound is no fault of the
    model; its positions carry the wider bound instead, and the calibration says why.
    """
    ratio = info.get("calibration_error_ratio")
    if ratio is None or ratio / judged_factor(info) <= INADEQUATE_RATIO:
        return None
    return "geometry"


def assessed(model: FourierModel, data: CalibrationData) -> FourierModel:
    """The model with ``info["calibration_error_ratio"]`` set, and ``info["stream"]`` when its
    frames came through JPEG (an MJPEG camera): what the quantisation costs every bound."""
    model.info.pop("stream", None)
    n_values = model.n_rows * model.n_pixels
    per_frame, used = frame_chi2(model, data)
    solved = model.out_of_sample(level(per_frame, used), data.frames.shape[0] * n_values)
    if (finding := find_jpeg(data.frames)) is not None:
        model.info["calibration_chi2"] = solved
        quantisation = stream_factor(model, data, finding.table)
        factor = max(quantisation, replayed_factor(model, data, finding.table))  # what the tracker reaches
        model.info["stream"] = {"kind": "jpeg", "quality": finding.quality, "bound_factor": round(factor, 3),
                                "quantisation_factor": round(quantisation, 3),
                                "focus_factor": round(stream_focus_factor(model, data, finding.table), 3),
                                "chi2_spread": round(chi2_spread(per_frame, used), 3)}
    elif "calibration_chi2" in model.info:  # a light that moved during calibration is the tracker's to solve
        model.info["calibration_chi2"] = stated_level(float(model.info["calibration_chi2"]), solved, n_values)
    for key in ("row_offset_gray", "row_chi2_share", "row_chi2_spread", "frame_offset_gray", FRAME_GAIN_RATE,
                LIGHT_PROFILE):
        model.info.pop(key, None)
    # the offset each frame draws afresh (the estimator takes it out of each frame as it takes a row's)
    if (offset := frame_offset_gray(model, data)) is not None:
        model.info["frame_offset_gray"] = round(offset, 4)
    # how fast the camera's gain moves from frame to frame (a camera hunting its exposure: the estimator's light
    # drifts at least that fast, core/estimator/filter.py)
    if (rate := frame_gain_rate(model, data)) is not None:
        model.info[FRAME_GAIN_RATE] = round(rate, 5)
    # the light along the stroke (the estimator carries its gain from place to place by it)
    if (profile := light_profile(model, data)) is not None:
        model.info[LIGHT_PROFILE] = profile
    if (row := row_offset_gray(model, data)) is not None:
        # what the estimator, which takes each row's offset out of a frame (core/estimator/kernel.py _normal), judges
        # a frame's χ² against: the level and the frames' spread with the offsets taken out as it takes them
        weights, residual, x_mm = solved_residuals(model, data)
        plain, without = rows_taken_out(weights, residual, model.n_rows, row)
        counted = (weights > 0).sum(axis=1)
        share = level(without, counted) / level(plain, counted)
        if share < ROW_LEVEL_SHARE:
            model.info["row_offset_gray"] = round(row, 4)
            model.info["row_chi2_share"] = round(share, 4)
            model.info["row_chi2_spread"] = round(frame_spread(x_mm, without, None, float(np.median(counted))), 3)
    errors = frame_errors(model, data)
    ratio = error_ratio(errors)
    model.info["calibration_error_ratio"] = round(ratio, 3) if np.isfinite(ratio) else None
    return model


def chi2_as_tracked(model: FourierModel, data: CalibrationData) -> float:
    """The calibration frames' χ² per used sample as the tracker measures a frame's (the light
    solved per frame): the level its running χ² is held against.

    The fit's own figure counts every sample of every row. A model that sees the row mean is
    judged on the row mean, where a residual the rows share does not average down as the noise
    does: a JPEG stream's quantisation of a strip whose rows agree is such a residual, and
    counted sample by sample it sets the level up to R times too low, so that every frame of
    the run looks changed.
    """
    return level(*frame_chi2(model, data))


def frame_chi2(model: FourierModel, data: CalibrationData) -> tuple[np.ndarray, np.ndarray]:
    """(χ² per used sample, samples used) of each calibration frame looked at that the model can
    solve, with its light solved as the tracker solves it (:func:`chi2_as_tracked`)."""
    weights, residual, _ = solved_residuals(model, data)
    used = (weights > 0).sum(axis=1)
    return np.einsum("kp,kp->k", weights, residual**2) / np.maximum(used, 1), used


def row_offset_gray(model: FourierModel, data: CalibrationData) -> float | None:
    """The σ (gray) of an offset each row of a strip draws afresh every frame (a sensor's row banding: its readout's
    reference drifting line by line), from the calibration frames' residuals; None where the model sees one row or
    the rows' mean residuals scatter no more than their noise (:data:`ROW_SIGNIFICANCE` of their sampling σ).
    Measured from each frame's row means against the next frame's along the stroke: what the model misses in a
    row moves with the place the frames see and drops out between neighbours; the light solved per frame takes
    the rows' common offset (the R/(R−1) of the rest)."""
    if model.n_rows < 2:
        return None
    weights, residual, x_mm = solved_residuals(model, data)
    n_frames, rows = residual.shape[0], model.n_rows
    if n_frames < 3:
        return None
    w = weights.reshape(n_frames, rows, -1)
    total = w.sum(axis=2)
    seen = total > 0
    means = np.where(seen, (w * residual.reshape(n_frames, rows, -1)).sum(axis=2) / np.where(seen, total, 1.0), 0.0)
    white = np.where(seen, 1.0 / np.where(seen, total, 1.0), 0.0)
    order = np.argsort(x_mm, kind="stable")
    means, white, seen = means[order], white[order], seen[order]
    both = seen[1:] & seen[:-1]
    if both.sum() < 3:
        return None
    # half a difference's square less the two frames' own noise: the offset's variance, one estimate a pair
    each = 0.5 * ((means[1:] - means[:-1]) ** 2 - white[1:] - white[:-1])[both]
    variance = float(each.mean()) * rows / (rows - 1)
    if variance <= ROW_SIGNIFICANCE * float(each.std()) / np.sqrt(each.size):
        return None
    return float(np.sqrt(variance))


def rows_taken_out(weights: np.ndarray, residual: np.ndarray, rows: int, row_gray: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(χ² per used sample as it is, and with each row's offset of σ ``row_gray`` taken out as the estimator takes
    it: less q²/(W + 1/σ²) a row, q its weighted residual sum, W its weights') of each frame."""
    n_frames = residual.shape[0]
    w = weights.reshape(n_frames, rows, -1)
    r = residual.reshape(n_frames, rows, -1)
    cost = np.einsum("krp,krp->k", w, r**2)
    q, total = (w * r).sum(axis=2), w.sum(axis=2)
    used = np.maximum((weights > 0).sum(axis=1), 1)
    return cost / used, (cost - (q * q / (total + 1.0 / row_gray**2)).sum(axis=1)) / used


def solved_residuals(model: FourierModel, data: CalibrationData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(weights, residuals ``(K, P)``, places mm) of each calibration frame looked at that the model can solve, with
    its light (a gain and an offset) solved as the tracker solves it."""
    weights, residual, x_mm, _, _ = light_solved(model, data)
    return weights, residual, x_mm


def light_solved(model: FourierModel, data: CalibrationData
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`solved_residuals` and each frame's light: (gain, offset gray) ``(K, 2)`` and their covariance from the
    noise model ``(K, 2, 2)``."""
    data = picked_frames(data)
    n_frames = data.x_mm.size
    frames = model.prepare(data.frames).reshape(n_frames, -1)
    values = model.predict(data.x_mm).reshape(n_frames, -1)
    weights = frame_weights(model, data, values)
    basis = np.stack([values, np.ones_like(values)], axis=2)  # the frame's gain and offset
    fisher = np.einsum("kp,kpi,kpj->kij", weights, basis, basis)
    score = np.einsum("kp,kpi,kp->ki", weights, basis, frames)
    solvable = np.linalg.det(fisher) > 0
    gain_offset = np.linalg.solve(fisher[solvable], score[solvable][..., None])[..., 0]
    residual = frames[solvable] - np.einsum("kpi,ki->kp", basis[solvable], gain_offset)
    return weights[solvable], residual, data.x_mm[solvable], gain_offset, np.linalg.inv(fisher[solvable])


def frame_offset_gray(model: FourierModel, data: CalibrationData) -> float | None:
    """The σ (gray) of an offset each frame draws afresh about its neighbours' (a one-row sensor's line offset at each
    readout, its black level's reference drifting frame by frame), None where it does not stand out of the offset's
    own estimation noise (:data:`ROW_SIGNIFICANCE` of its sampling σ).

    Measured as :func:`row_offset_gray` measures a row's: each frame's offset (its light solved as the tracker solves
    it) against the next frame's along the stroke, half a difference's square less the two estimates' own variance
    (the noise model's, times the frames' χ² level where the model leaves more than noise): stray light that drifts
    over the sweep and what the model misses at a place drop out between neighbours, an offset drawn each frame does
    not. (A gain drawn afresh is not taken out so: the gain and the position share the print's shape over a field of
    a few periods, and a camera's gain hunting swings further than a frame's own draw; the light's states and jumps
    follow it.)"""
    weights, residual, x_mm, light, covariance = light_solved(model, data)
    if x_mm.size < 3:
        return None
    used = (weights > 0).sum(axis=1)
    chi2 = np.einsum("kp,kp->k", weights, residual**2) / np.maximum(used, 1)
    order = np.argsort(x_mm, kind="stable")
    offset, own = light[order, 1], covariance[order, 1, 1] * max(1.0, level(chi2, used))
    each = 0.5 * (np.diff(offset) ** 2 - own[1:] - own[:-1])
    variance = float(each.mean())
    if variance <= ROW_SIGNIFICANCE * float(each.std()) / np.sqrt(each.size):
        return None
    return float(np.sqrt(variance))


def frame_gain_rate(model: FourierModel, data: CalibrationData) -> float | None:
    """How fast the light's gain walks from frame to frame (relative, 1/√s: a random walk's σ after a second), None
    where it does not stand out of its estimate's noise (:data:`ROW_SIGNIFICANCE` of its sampling σ) or the frames
    have no times.

    A camera hunting its exposure steps its gain by a percent between frames, a regulated lamp holds it for minutes:
    the one is a rig's property calibration's frames show, and the estimator lets its light drift at least that fast
    (a light held where it hunts puts each step into the position over less than a period). Measured from each
    frame's gain (its light solved as the tracker solves it) by how the square of the difference between two frames
    grows with the time between them, one frame apart against two: a random walk's grows with the time, while what
    is drawn afresh each frame (the noise, a stream's quantisation) or belongs to the place the frame sees (what the
    model misses there, the print's marks, over the few hundredths of a millimetre between neighbours) does not. A
    lamp's flicker at twice the mains (``meta["mains_hz"]``, the estimator's own where it does not say), which the
    estimator follows with states of its own, is fitted out of the gains first."""
    from graytrack.core.estimator.settings import TUNABLES
    from graytrack.core.recording import MAINS_HZ

    picked = picked_frames(data)
    if picked.t_s is None:
        return None
    _, _, _, light, _ = light_solved(model, data)
    t = np.asarray(picked.t_s, dtype=np.float64)
    if light.shape[0] != t.size or t.size < 8:  # (a frame the model could not solve breaks the sequence)
        return None
    gain = light[:, 0]
    mains = float(picked.meta.get(MAINS_HZ, TUNABLES["mains_hz"].default) or 0.0)
    if mains > 0.0:
        phase = 4.0 * np.pi * mains * t
        basis = np.stack([np.ones_like(t), np.cos(phase), np.sin(phase)], axis=1)
        fitted, *_ = np.linalg.lstsq(basis, gain, rcond=None)
        gain = gain - basis[:, 1:] @ fitted[1:]
    one, two = np.diff(gain) ** 2, (gain[2:] - gain[:-2]) ** 2
    dt_one, dt_two = np.diff(t), t[2:] - t[:-2]
    longer = dt_two - 0.5 * (dt_one[1:] + dt_one[:-1])
    usable = longer > 0.0
    if usable.sum() < 4:
        return None
    each = ((two - 0.5 * (one[1:] + one[:-1]))[usable]) / longer[usable]
    variance = float(each.mean())
    if variance <= ROW_SIGNIFICANCE * float(each.std()) / np.sqrt(each.size):
        return None
    return float(np.sqrt(variance))


def light_profile(model: FourierModel, data: CalibrationData) -> dict | None:
    """The light's gain along the stroke, relative to its mean (``{"x_mm": [...], "gain": [...]}``, the means of
    stretches of :data:`PROFILE_FRAMES` calibration frames, at their mean places), None where it does not stand out
    of its own scatter (:data:`ROW_SIGNIFICANCE` standard errors of the stretches' spread beyond what the scatter
    within them gives).

    A lamp lights the print unevenly (its spot, a gradient across a long stroke) and the print's ink is not equally
    dark everywhere: the light a frame sees changes with the place it sees, fixed to the print, while the model's
    series holds what is fixed to the pixels. Calibration's frames, each solved for its light at the grating's place,
    show it as a gain that follows the place; the estimator carries its gain from place to place by it instead of
    letting its light drift. The scatter within a stretch (the noise, what the model misses between neighbouring
    places) is the measure of each stretch's mean: no noise model is trusted for it."""
    _, _, x_mm, light, _ = light_solved(model, data)
    if x_mm.size < 4 * PROFILE_FRAMES:
        return None
    order = np.argsort(x_mm, kind="stable")
    x_sorted, gain = x_mm[order], light[order, 0]
    stretches = x_sorted.size // PROFILE_FRAMES
    cut = stretches * PROFILE_FRAMES
    places = x_sorted[:cut].reshape(stretches, PROFILE_FRAMES)
    gains = gain[:cut].reshape(stretches, PROFILE_FRAMES)
    means = gains.mean(axis=1)
    within = gains.var(axis=1, ddof=1) / PROFILE_FRAMES  # each stretch's mean's variance from its own scatter
    between = float(np.var(means, ddof=1))
    # the stretches' spread beyond their means' own, in standard errors of that spread (a χ² of stretches - 1 degrees)
    excess = (between - float(within.mean())) / (float(within.mean()) * math.sqrt(2.0 / (stretches - 1)))
    if not excess > ROW_SIGNIFICANCE:
        return None
    relative = means / float(means.mean())
    return {"x_mm": [round(float(x), 5) for x in places.mean(axis=1)],
            "gain": [round(float(g), 6) for g in relative]}


def level(per_frame: np.ndarray, used: np.ndarray) -> float:
    """The χ² per used sample over all frames (:func:`frame_chi2`)."""
    return float((per_frame * used).sum() / max(used.sum(), 1))


def chi2_spread(per_frame: np.ndarray, used: np.ndarray) -> float:
    """The frames' χ² spread about its level over what white noise in as many samples gives it
    (√(2/samples) of the level), at least 1: core/compression.py ``stream_chi2_spread``. The larger of
    one frame's and that of a mean over :data:`SPREAD_WINDOW` frames in their order (against white
    noise's over as many): a stream's χ² wanders with the place the frames see, and the tracker judges
    running means (the `lab` strip at quality 75: 3.2 a frame, 3.7 over 20, a steady run's blur
    suspected on 5 frames with the first)."""
    if per_frame.size < 2:
        return 1.0
    white = np.sqrt(2.0 / max(float(np.median(used)), 1.0))
    relative = per_frame / max(float(np.mean(per_frame)), 1e-300)
    spread = float(np.std(relative)) / white
    if relative.size >= 2 * SPREAD_WINDOW:
        means = np.convolve(relative, np.full(SPREAD_WINDOW, 1.0 / SPREAD_WINDOW), mode="valid")
        spread = max(spread, float(np.std(means)) * np.sqrt(SPREAD_WINDOW) / white)
    return float(max(1.0, spread))


def stream_factor(model: FourierModel, data: CalibrationData, table: np.ndarray) -> float:
    """The quantisation's widening of the bound over the calibration frames (compression.bound_factor),
    on the frames' own rows: JPEG blocks are cut from the image the camera sent, not the row mean."""
    x = picked_frames(data).x_mm
    values, slopes = model.predict(x, with_derivative=True)
    shape = (x.size,) + data.frames.shape[1:]
    sigma2 = model.noise().variance(values)
    return bound_factor(np.broadcast_to(slopes, shape), np.broadcast_to(sigma2, shape), table)


def replayed_factor(model: FourierModel, data: CalibrationData, table: np.ndarray, seed: int = 0) -> float:
    """How much a JPEG stream widens the bound of the positions the tracker gives: the model's own
    images at the calibration frames' places, with the sensor's noise (seeded draws), through 8 bits
    and the stream's quantisation ``table`` (compression.round_trip), placed as the tracker places
    a frame (:func:`frame_errors`: the light profiled out), their rms error over the rms white-noise
    bound.

    :func:`stream_factor` counts the quantisation as an independent error of q²/12 per coefficient
    against an estimator that weighs the coefficients by it. Neither holds on a stream whose steps
    are several times the sensor's noise: a coefficient is rounded the same way frame after frame
    (no noise dithers it), small ones are zeroed, and the tracker weighs pixels, not coefficients.
    On the lab strip at quality 75 (σ 1.05 gray) that factor says 2.41 where the replay gives 3.2
    and the model's own calibration frames sit 3.21 white bounds off: a run judged by it is 1.48× its widened
    bound with 1 % of its frames 4+ bounds off unflagged."""
    error2, bound2 = [], []
    for streamed in replayed_frames(model, picked_frames(data), table, seed):
        errors = frame_errors(model, streamed)
        if errors is not None:
            error2.append(errors[1] ** 2)
            bound2.append(errors[2])
    if not error2:
        return 1.0
    return float(np.sqrt(np.mean(np.concatenate(error2)) / np.mean(np.concatenate(bound2))))
