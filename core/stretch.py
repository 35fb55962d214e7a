"""The stretch of the image across the pixels, measured from one frame: a magnification change.

A lens whose magnification moves by m (warming up, a temperature cycle) scales every pixel's
footprint on the target about the optical axis: the pixel that saw target offset ``s_u`` sees
``s_u + m·(s_u − s_axis)``. Part of that is a shift of the whole image (``m·(s_c − s_axis)``, the
line's centre against the axis): the tracker takes it for a position and cannot tell it from one.
The rest is a stretch about the line's centre, ``m·(s_u − s_c)``, which leaves in the frame's
residual the shape ``m·F'_u·(s_u − s_c)``: the frame's slope at each sample times its place along
the line. Fitted by weighted least squares with the shapes the solve already had (the position's
slope, the light's gain and offset), so what they explain is not taken for a stretch, it gives m
and its standard error from the frame's own noise. One frame of a 16-row strip of 100 px knows m
to ~250 ppm; a run's frames together, to a few ppm (core/watches/magnification.py).
"""

from __future__ import annotations

import math

import numpy as np

from graytrack.core import kernels, small_linalg

OUTLIER_Z = 4.0  # a sample this many of its σ off the model is left out of the stretch
FOCUS_STEP_PERIODS = 1e-3  # the curvature's finite-difference step, in periods
# The stretch of a frame by one compiled call (:func:`_stretches`); False: numpy's :func:`stretch`.
COMPILED = kernels.COMPILED


def stretch(values: np.ndarray, slopes: np.ndarray, residual: np.ndarray, weights: np.ndarray,
            offsets_mm: np.ndarray, curvature: np.ndarray | None = None) -> tuple[float, float]:
    """(m, its standard error), dimensionless, from one frame: the model's ``values`` and ``slopes``
    (∂F/∂x, gray/mm) at the solved position, the frame's ``residual`` and information ``weights``
    (1/σ², 0 for a sample set aside), and each sample's target offset ``offsets_mm``; with its
    ``curvature`` (∂²F/∂x²) a change of focus is fitted too (a blur spreads as ½Δσ²·F'', which on
    a line shorter than a period partly looks like a stretch: a focus drift of half a pixel read as
    a steady stretch on a quarter of its frames). (nan, inf) when the frame cannot tell."""
    # a sample far beyond its noise (a pixel gone bad that the solve kept, a glint's edge) is no stretch:
    # one stuck pixel off the centre, the same on every frame, read as a steady 300 ppm on a 16-row strip
    w = np.where(residual * residual * weights > OUTLIER_Z * OUTLIER_Z, 0.0, weights)
    total = w.sum()
    if not total > 0:
        return math.nan, math.inf
    centred = offsets_mm - float(w @ offsets_mm) / total
    columns = [slopes * centred, slopes, values, np.ones_like(values)]
    if curvature is not None:
        columns.append(curvature)
    shapes = np.stack(columns)  # (4 or 5, P)
    weighted = shapes * w
    normal = weighted @ shapes.T
    try:
        covariance = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return math.nan, math.inf
    variance = covariance[0, 0]
    if not variance > 0:
        return math.nan, math.inf
    m = float(covariance[0] @ (weighted @ residual))
    return m, math.sqrt(variance)


def frame_stretch(tracker, batch, k: int, solution) -> tuple[float, float]:
    """:func:`stretch` of batch frame ``k`` at its solution (one evaluation of the model there)."""
    if compiled_for(tracker):
        return FrameStretch(tracker, batch, k, solution)()
    weights = batch.weights(k)
    if solution.rejected_mask is not None:
        weights = weights * ~solution.rejected_mask
    residual = batch.residuals(k, solution.x_mm, solution.gain, solution.offset_gray)
    offsets = tracker.model.target_offset().reshape(-1)
    if not math.isfinite(solution.focus_sigma):  # the focus held: the stretch alone (its full power)
        values, slopes = tracker.evaluator.evaluate(np.array([solution.x_mm]))
        return stretch(values[0], slopes[0], residual, weights, offsets)
    # the tracker solved a change of focus for this frame: the stretch beside it (the curvature by the
    # slopes a thousandth of a period apart)
    step = tracker.model.period_mm * FOCUS_STEP_PERIODS
    values, slopes = tracker.evaluator.evaluate(np.array([solution.x_mm - step, solution.x_mm, solution.x_mm + step]))
    return stretch(values[1], slopes[1], residual, weights, offsets, (slopes[2] - slopes[0]) / (2.0 * step))


def compiled_for(tracker) -> bool:
    """Whether ``tracker``'s stretches are computed by the compiled kernel (its model evaluated by the
    table kernel: :func:`stretches`), else by numpy frame by frame."""
    return COMPILED and isinstance(tracker.evaluator, kernels.TableEvaluator)


class FrameStretch:
    """One solved frame's stretch, computed when a watch asks (``FrameSign.stretch``): it keeps what
    the stretch is computed from, so that a chunk of frames waiting for the monitor is computed in
    one compiled call (:func:`stretches`) rather than a dozen numpy calls a frame."""

    __slots__ = ("tracker", "batch", "k", "solution")

    def __init__(self, tracker, batch, k: int, solution) -> None:
        self.tracker, self.batch, self.k, self.solution = tracker, batch, k, solution

    def __call__(self) -> tuple[float, float]:
        if not compiled_for(self.tracker):
            return frame_stretch(self.tracker, self.batch, self.k, self.solution)
        m, sigma = stretches([self])
        return float(m[0]), float(sigma[0])


class Measured:
    """A frame's stretch computed already (``FrameSign.stretch`` as :class:`FrameStretch` would
    return it): a chunk's stretches made by one compiled call and handed out frame by frame."""

    __slots__ = ("m", "sigma")

    def __init__(self, m: float, sigma: float) -> None:
        self.m, self.sigma = m, sigma

    def __call__(self) -> tuple[float, float]:
        return self.m, self.sigma


def chunk_stretches(entries: list, asked: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(m, σ) of every frame of a chunk, computed for the frames ``asked`` (indices into ``entries``,
    each a ``FrameSign.stretch``): by one compiled call (:func:`stretches`) when they are all
    :class:`FrameStretch` of one compiled tracker, else by each frame's own call; NaN and inf elsewhere.
    Frame by frame :func:`_stretches` reads only its own frame: the same numbers as each frame's
    :class:`FrameStretch` (tests/core/test_stretch_fast.py)."""
    n = len(entries)
    m, sigma = np.full(n, math.nan), np.full(n, math.inf)
    if asked.size:
        frames = [entries[i] for i in asked]
        if all(type(frame) is FrameStretch for frame in frames) and len({id(f.tracker) for f in frames}) == 1 \
                and compiled_for(frames[0].tracker):
            m[asked], sigma[asked] = stretches(frames)
        else:
            m[asked], sigma[asked] = np.array([frame() for frame in frames], dtype=np.float64).reshape(-1, 2).T
    return m, sigma


def stretches(frames: list[FrameStretch]) -> tuple[np.ndarray, np.ndarray]:
    """(m, σ) of each of ``frames`` (all of one tracker, :func:`compiled_for` it), by one compiled
    call: :func:`stretch`'s least squares frame by frame, solved by elimination rather than numpy's
    inverse (the same numbers to rounding: tests/core/test_stretch_fast.py)."""
    tracker = frames[0].tracker
    n = len(frames)
    y, w, x, gain, offset, focused, work, m, sigma = _buffers(tracker, n)
    if n > 1 and all(frame.batch is frames[0].batch for frame in frames):  # a batch's frames: copied at once
        solutions = [frame.solution for frame in frames]
        batch, at = frames[0].batch, [frame.k for frame in frames]
        y[:] = batch.frames[at]
        w[:] = [batch.weights(k) for k in at]
        for i, solution in enumerate(solutions):
            if solution.rejected_mask is not None:
                np.multiply(w[i], ~solution.rejected_mask, out=w[i])
        x[:] = [solution.x_mm for solution in solutions]
        gain[:] = [solution.gain for solution in solutions]
        offset[:] = [solution.offset_gray for solution in solutions]
        focused[:] = [math.isfinite(solution.focus_sigma) for solution in solutions]
    else:  # live tracking's one frame, or frames of several batches
        for i, frame in enumerate(frames):
            solution, batch = frame.solution, frame.batch
            y[i] = batch.frames[frame.k]
            weights = batch.weights(frame.k)
            if solution.rejected_mask is not None:
                np.multiply(weights, ~solution.rejected_mask, out=w[i])
            else:
                w[i] = weights
            x[i], gain[i], offset[i] = solution.x_mm, solution.gain, solution.offset_gray
            focused[i] = math.isfinite(solution.focus_sigma)
    _stretches(x, gain, offset, focused, y, w, _target_offsets(tracker), tracker.model.period_mm * FOCUS_STEP_PERIODS,
               tracker.evaluator._args, work, m, sigma)
    return m, sigma


def _buffers(tracker, n: int) -> tuple[np.ndarray, ...]:
    """The arrays of :func:`stretches` for ``n`` frames: those of one frame (live tracking asks frame
    by frame) kept on the tracker's evaluator, to be overwritten by its next frame."""
    kept = getattr(tracker.evaluator, "_stretch_buffers", None) if n == 1 else None
    if kept is not None:
        return kept
    n_values = tracker.model.n_rows * tracker.model.n_pixels
    made = (np.empty((n, n_values)), np.empty((n, n_values)), np.empty(n), np.empty(n), np.empty(n),
            np.empty(n, dtype=np.bool_), np.empty((4, 3, n_values)), np.empty(n), np.empty(n))
    if n == 1:
        tracker.evaluator._stretch_buffers = made
    return made


def warm(tracker) -> None:
    """Compile (or load from numba's cache) the stretch kernel for ``tracker``'s model now, at model
    install: no live frame waits for the compiler (tests/core/test_install_warm.py)."""
    if not compiled_for(tracker):
        return
    y, w, x, gain, offset, focused, work, m, sigma = _buffers(tracker, 1)
    w[:] = 0.0  # no sample: the model evaluated once, nothing solved
    x[0], gain[0], offset[0], focused[0] = 0.0, 1.0, 0.0, False
    _stretches(x, gain, offset, focused, y, w, _target_offsets(tracker), 1.0, tracker.evaluator._args, work, m, sigma)


def _target_offsets(tracker) -> np.ndarray:
    """Each sample's target offset (mm), flat, kept on the tracker's evaluator (made once per model)."""
    offsets = getattr(tracker.evaluator, "_stretch_offsets", None)
    if offsets is None:
        offsets = np.ascontiguousarray(tracker.model.target_offset().reshape(-1), dtype=np.float64)
        tracker.evaluator._stretch_offsets = offsets
    return offsets


def _stretches(x: np.ndarray, gain: np.ndarray, offset: np.ndarray, focused: np.ndarray, y: np.ndarray,
               w: np.ndarray, offsets: np.ndarray, step: float, model: tuple, work: np.ndarray, m: np.ndarray,
               sigma: np.ndarray) -> None:
    """:func:`stretch` of frames ``y`` ``(K, P)`` under weights ``w`` at their solutions (x, gain,
    offset; ``focused``: with the curvature beside it) into ``m``, ``sigma``; ``work`` (4, 3, P)."""
    values, slopes, smooth = work[0], work[1], work[2, 0]
    shapes = work[3]
    normal = np.empty((5, 5))
    rhs = np.empty((5, 2))
    for i in range(x.size):
        m[i], sigma[i] = math.nan, math.inf
        if focused[i]:
            _evaluate(x[i] - step, model, values[0], slopes[0], smooth)
            _evaluate(x[i] + step, model, values[2], slopes[2], smooth)
        _evaluate(x[i], model, values[1], slopes[1], smooth)
        n = 5 if focused[i] else 4
        total = 0.0
        centre = 0.0
        for p in range(y.shape[1]):
            r = y[i, p] - gain[i] * values[1, p] - offset[i]
            wp = w[i, p]
            if r * r * wp > OUTLIER_Z * OUTLIER_Z:
                wp = 0.0
            shapes[0, p], shapes[1, p] = r, wp  # the residual and the weight kept
            total += wp
            centre += wp * offsets[p]
        if not total > 0:
            continue
        centre /= total
        for a in range(n):
            rhs[a, 0], rhs[a, 1] = 0.0, 0.0
            for b in range(n):
                normal[a, b] = 0.0
        rhs[0, 0] = 1.0
        for p in range(y.shape[1]):
            wp = shapes[1, p]
            if wp == 0.0:
                continue
            s = slopes[1, p]
            c0, c1, c2, c4 = s * (offsets[p] - centre), s, values[1, p], 0.0
            if n == 5:
                c4 = (slopes[2, p] - slopes[0, p]) / (2.0 * step)
            column = (c0, c1, c2, 1.0, c4)
            r = shapes[0, p]
            for a in range(n):
                wa = wp * column[a]
                rhs[a, 1] += wa * r
                for b in range(a, n):
                    normal[a, b] += wa * column[b]
        for a in range(n):
            for b in range(a):
                normal[a, b] = normal[b, a]
        if not _eliminate(normal[:n, :n], rhs[:n]):
            continue
        if rhs[0, 0] > 0:
            m[i], sigma[i] = rhs[0, 1], math.sqrt(rhs[0, 0])


def _evaluate(x: float, model: tuple, values: np.ndarray, slopes: np.ndarray, smooth: np.ndarray) -> None:
    kernels._evaluate_into(x, *model, values, slopes, smooth)


_eliminate = small_linalg._eliminate
if kernels.COMPILED:
    _jit = kernels.numba.njit(cache=True, nogil=True, error_model="numpy")
    _evaluate = _jit(_evaluate)
    _stretches = _jit(_stretches)
