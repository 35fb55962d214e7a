"""One frame of the estimator in one compiled call: predict the state to the frame's time, then
update it with the frame's gray values (and the grating, where it is fused) by Gauss–Newton on the
posterior, with robust reweighting as the measurement's outlier model.

The update minimises, over the active states s,

    Σ_p ρ_p w_p (y_p − h_p(s))²  +  (s − s⁻)ᵀ (P⁻)⁻¹ (s − s⁻)  +  (z − x)² / σ_z²

where h is the calibrated model seen through the nuisance states (state.py):

    h_p = (g + a₁ B₁(u_p) + a₂ B₂(u_p)) · (F_p(ξ) + F′_p(ξ) (m t_p + θ r_p) + ½ b δ² F″_p(ξ)) + o,
    ξ   = x + c + L m

(F the model's values along the pixels at image position ξ, t_p a pixel's target coordinate from
the ROI's centre, r_p its row from the strip's middle, δ the pixel pitch, w_p the noise model's
weight, ρ_p the robust weight). For a linear-Gaussian model the minimum of that cost is the
innovation's χ² against its covariance, with as many degrees of freedom as samples: the one test
every flag comes from (filter.py). The posterior information is the Gauss–Newton normal matrix at
the minimum.

Written once in the subset of Python numba compiles; without numba it runs as Python (slowly, the
same numbers).
"""

from __future__ import annotations

import math

import numpy as np

from graytrack.core import kernels
from graytrack.core.estimator.light_modes import reweigh
from graytrack.core.estimator.state import (A1, A2, B, BD, BE, BH, BL, BR, BW, C, D, DRIFTS, FC, FS, G, L, M, N_STATE,
                                            OFS, SK, STATE, T, UNREAD, V, X)

# The state's layout as this file was compiled for. numba keys its cache by this file's stamp alone, not
# by the indices it compiles in from state.py: a cache made for another layout indexes the wrong states
# (seen: NaN or a silently wrong skew). A layout change must therefore change this file, and does:
LAYOUT = ("x_mm v_mm_s gain offset_gray field_tilt field_bow focus_px2 stretch place_mm lever_mm turn_mm_row skew_s "
          "band_depth band_left_mm band_right_mm band_speed_mm_s band_edge_mm band_haze_gray skew_rate_s_s jitter_mm "
          "focus_rate_px2_s flicker_cos flicker_sin")
UNREAD_LAYOUT = "jitter_mm skew_rate_s_s focus_rate_px2_s flicker_cos flicker_sin"
if LAYOUT != " ".join(entry.name for entry in STATE) or UNREAD_LAYOUT != " ".join(STATE[i].name for i in UNREAD):
    raise ImportError("core/estimator/state.py's layout differs from kernel.LAYOUT or UNREAD_LAYOUT: update them "
                      "with it (they key the compiled kernel's cache)")
_UNREAD = np.array(UNREAD, dtype=np.int64)  # (compiled in as a constant)
_DRIFTS = np.array(DRIFTS, dtype=np.int64)  # (compiled in as a constant)
MAD_TO_SIGMA = 1.4826
ROOT_2, ROOT_2PI = math.sqrt(2.0), math.sqrt(2.0 * math.pi)
ROBUST_ROUNDS = 6  # reweightings at most: the redescending weights settle in 2–3 on a frame with a blob
CURVATURE_STEP_PERIODS = 1e-3  # forward-difference step of F″ from the slopes, in periods (error ~ 3 % at order 5)
# out_stats layout
# (S_POSTERIOR: 1 where the update made the posterior covariance, params[U_POSTERIOR]; S_WEIGHED: samples the robust
# weights took down, not aside; S_LIGHT: the light's drifting mode's probability after the frame, where params[U_LIGHT]
# asked it weighed)
(S_COST, S_RESIDUAL, S_PRIOR, S_USED, S_REJECTED, S_ITER, S_XINFO, S_RMS, S_GRATING, S_CONVERGED,
 S_POSTERIOR, S_WEIGHED, S_LIGHT) = range(13)
S_GAIN = 13  # from here, one row of N_STATE a state of UNREAD: its gain on each state solved under the solve's prior
N_STATS = S_GAIN + len(UNREAD) * N_STATE  # (conditioned)
# the update's numbers in one array (a frame's call passes one array, not a dozen arguments: each argument costs
# the call ~0.1 µs): the noise model's read variance, shot gain and dark level, the pixel pitch and the period (mm),
# the fused grating's reading (mm) and weight (1/σ², 0: none), robust weights on (1) or off (0), their core and cut
# (σ), the iterations at most, the tolerance (mm); whether the prior is first predicted (1) or taken as it is (0), over
# how long (s), the acceleration's variance (mm²/s⁴) held over the interval and that of one white within it (predict);
# whether the posterior covariance is made too (1: ``embed`` into
# ``P_post``, for the update a frame most likely keeps); whether the iterations start from ``s`` and ``rho`` as passed
# (1: the frame solved again from its own solution and weights) or from the prior's mean and full weights (0); from
# the calibration's χ² level at the frame's place (each sample's variance is the noise model's times it: what the
# model's own error adds to a sample, as calibration measured it); the samples a row and the precision of an offset
# each row draws afresh every frame (gray⁻², 0: none; _normal); the softest a band's penumbra may be solved to (mm:
# a step that would take its σ below is taken to it, as onto any bound); where the image places the carriage at the
# frame's place as calibration measured it against the grating (mm: its error map, filter.py calibration_error, added
# to the place every sample is evaluated at); from U_LIGHT whether the frame's reading of the light is weighed under
# both its modes where the posterior is made (1, else 0: light_modes.py reweigh, in this call rather than one more a
# frame) and reweigh's numbers: the drift's variances over the interval, whether the frame was predicted drifting (1/0)
# and the chain's probability for it; from U_FLICKER the flicker's turn over the
# interval (predict's ``flicker``: four numbers); from U_RATES on each state's rate (predict's ``rates2``)
(U_READ, U_SHOT, U_DARK, U_PITCH, U_PERIOD, U_GRATING_Z, U_GRATING_W, U_ROBUST, U_CORE, U_CUT, U_ITERATIONS,
 U_TOLERANCE, U_PREDICT, U_DT, U_ACCELERATION, U_ACCELERATION_WHITE, U_POSTERIOR, U_WARM, U_LEVEL, U_ROW_LENGTH,
 U_ROW_PRECISION, U_BAND_SHARPEST, U_MAPPED, U_LIGHT) = range(24)
U_FLICKER = U_LIGHT + 5
U_RATES = U_FLICKER + 4
N_PARAMS = U_RATES + N_STATE
# the pixels' constants in one (4, P) array: target coordinate from the ROI's centre, row from the strip's middle,
# the two Legendre terms across the line
(PX_TARGET, PX_ROW, PX_B1, PX_B2) = range(4)


def _cholesky(A: np.ndarray, factor: np.ndarray) -> bool:
    """``factor``'s lower triangle becomes the Cholesky factor of the symmetric ``A`` (its lower triangle read);
    False where ``A`` is not positive definite. Every matrix the estimator inverts is a covariance or an
    information (positive definite); written out, for at 8–19 states a general LAPACK routine through numba
    costs its checks and copies two to three times the arithmetic."""
    n = A.shape[0]
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d -= factor[j, k] * factor[j, k]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        factor[j, j] = d
        for i in range(j + 1, n):
            acc = A[i, j]
            for k in range(j):
                acc -= factor[i, k] * factor[j, k]
            factor[i, j] = acc / d
    return True


def _inverse(A: np.ndarray) -> np.ndarray:
    """``A``⁻¹ of a symmetric positive-definite ``A`` through its Cholesky factor (LAPACK's general inverse
    where it is not positive definite: an indefinite matrix inverts as before, a singular one raises)."""
    n = A.shape[0]
    factor = np.zeros((n, n))
    if not _cholesky(A, factor):
        return np.linalg.inv(A)
    for j in range(n):  # the factor's inverse, in place (lower triangular)
        factor[j, j] = 1.0 / factor[j, j]
        for i in range(j + 1, n):
            acc = 0.0
            for k in range(j, i):
                acc -= factor[i, k] * factor[k, j]
            factor[i, j] = acc / factor[i, i]
    out = np.empty((n, n))
    for i in range(n):  # A⁻¹ = L⁻ᵀ L⁻¹
        for j in range(i + 1):
            acc = 0.0
            for k in range(i, n):
                acc += factor[k, i] * factor[k, j]
            out[i, j] = acc
            out[j, i] = acc
    return out


def _solve(A: np.ndarray, rhs: np.ndarray, out: np.ndarray, factor: np.ndarray) -> None:
    """``out`` = ``A``⁻¹ ``rhs`` for a symmetric positive-definite ``A`` by its Cholesky factor (into ``factor``);
    LAPACK's general solve where it is not positive definite."""
    n = A.shape[0]
    if not _cholesky(A, factor):
        out[:] = np.linalg.solve(A, rhs)
        return
    for i in range(n):  # L u = rhs
        acc = rhs[i]
        for k in range(i):
            acc -= factor[i, k] * out[k]
        out[i] = acc / factor[i, i]
    for i in range(n - 1, -1, -1):  # Lᵀ out = u
        acc = out[i]
        for k in range(i + 1, n):
            acc -= factor[k, i] * out[k]
        out[i] = acc / factor[i, i]


def carried(P: np.ndarray, states: np.ndarray, x: int) -> float:
    """What knowing the ``states`` exactly would remove from state ``x``'s variance under the covariance ``P``:
    P_xS P_SS⁻¹ P_Sx (the Schur complement; 0 where P_SS is singular: states the frames pin exactly carry
    nothing)."""
    n = states.size
    block, across, out, factor = np.empty((n, n)), np.empty(n), np.empty(n), np.zeros((n, n))
    for i in range(n):
        across[i] = P[states[i], x]
        for j in range(n):
            block[i, j] = P[states[i], states[j]]
    if not _cholesky(block, factor):
        return 0.0  # (a covariance's block: not positive definite only where singular)
    _solve(block, across, out, factor)
    removed = 0.0
    for i in range(n):
        removed += across[i] * out[i]
    return removed


def information(P: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The inverse of ``P``'s block over the states ``idx``."""
    n = idx.size
    block = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            block[i, j] = P[idx[i], idx[j]]
    return _inverse(block)


def conditioned(s: np.ndarray, s_prior: np.ndarray, P_prior: np.ndarray, idx: np.ndarray, info: np.ndarray,
                gain: np.ndarray) -> None:
    """In place: each state of UNREAD its posterior mean from the states solved, and its gains on them into
    ``gain`` (row k of N_STATE the k-th's). No sample and no reading sees them (state.py UNREAD), so they are never
    solved: each posterior is the prior conditioned on the states solved, s_u = s_u⁻ + K (s − s⁻) with
    K = P⁻_u,idx · ``info`` (the prior's information over ``idx``), exactly what solving them with the others
    gives; K = 0 where it is not a state of this estimator (no variance)."""
    n = idx.size
    for k in range(_UNREAD.size):
        u = _UNREAD[k]
        row = k * N_STATE
        for j in range(n):
            gain[row + j] = 0.0
        if not P_prior[u, u] > 0.0:
            continue
        tied = False  # (a state the prediction has not tied to any solved one keeps its prior: gains of nought)
        for j in range(n):
            if P_prior[u, idx[j]] != 0.0:
                tied = True
                break
        if not tied:
            continue
        acc = s_prior[u]
        for j in range(n):
            g = 0.0
            for i in range(n):
                g += P_prior[u, idx[i]] * info[i, j]
            gain[row + j] = g
            acc += g * (s[idx[j]] - s_prior[idx[j]])
        s[u] = acc


def embed(P: np.ndarray, A: np.ndarray, idx: np.ndarray, sigma: np.ndarray, gain: np.ndarray) -> None:
    """In place: ``P`` (the prior's covariance) has its block over ``idx`` made ``A``⁻¹ (the posterior); states
    outside ``idx`` keep their own variance and lose their correlation with those inside, but for the states of
    UNREAD, whose posterior is their prior conditioned on them with the solve's gains K (:func:`conditioned`: a
    solve's ``stats[S_GAIN:]``): P_u,idx = K_u P⁺, P_uw = P⁻_uw − K_u P⁻_idx,w + K_u P⁺ K_wᵀ. ``sigma``: every
    state's σ out (a negative variance's 0)."""
    inner = _inverse(A)
    n, total, m = idx.size, P.shape[0], _UNREAD.size
    inside = np.zeros(total, dtype=np.bool_)
    for i in range(n):
        inside[idx[i]] = True
    # each unread state's gain row carried through the posterior (K_u P⁺), and what the prior keeps of it
    live = np.zeros(m, dtype=np.bool_)
    carried = np.zeros((m, n))
    kept = np.zeros((m, m))
    for a in range(m):
        u, row = _UNREAD[a], a * N_STATE
        live[a] = False
        if P[u, u] > 0.0 and not inside[u]:
            # (with gains of nought, what embedding it would carry and keep is what it holds: skipped, the same)
            for j in range(n):
                if gain[row + j] != 0.0:
                    live[a] = True
                    break
    for a in range(m):
        if not live[a]:
            continue
        u, row = _UNREAD[a], a * N_STATE
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += gain[row + j] * inner[j, i]
            carried[a, i] = acc
        for b in range(m):
            if not live[b]:
                continue
            w = _UNREAD[b]
            acc = P[u, w]
            for j in range(n):
                acc -= gain[row + j] * P[idx[j], w]
            kept[a, b] = acc
    for i in range(total):
        for j in range(total):
            if inside[i] != inside[j]:
                P[i, j] = 0.0
    for i in range(n):
        for j in range(n):
            P[idx[i], idx[j]] = inner[i, j]
    for a in range(m):
        if not live[a]:
            continue
        u, row = _UNREAD[a], a * N_STATE
        for i in range(n):
            P[u, idx[i]] = carried[a, i]
            P[idx[i], u] = carried[a, i]
        for b in range(m):
            if not live[b]:
                continue
            w, row_w = _UNREAD[b], b * N_STATE
            acc = kept[a, b]
            for i in range(n):
                acc += carried[a, i] * gain[row_w + i]
            P[u, w] = acc
    for i in range(total):
        sigma[i] = 0.0 if P[i, i] < 0.0 else math.sqrt(P[i, i])


def scores(P_prior: np.ndarray, A: np.ndarray, idx: np.ndarray, s: np.ndarray, s_prior: np.ndarray,
           families: np.ndarray, dt: float, out: np.ndarray) -> bool:
    """Each jump family's score statistic of the innovation into ``out`` (filter._ranked's test): with Λ the
    prior's information over ``idx`` and P⁺ = ``A``⁻¹ the posterior's covariance, g = Λ(s⁺ − s⁻) and its
    covariance Λ − ΛP⁺Λ; a family's statistic is g's part in its directions normalised by that covariance.
    ``families``: (F, 3) rows of (kind, i, j) over the active states' places: kind 0 one state (i), 1 two
    (i, j), 2 the motion (a velocity jump in the last interval: the position i and the velocity j). Returns
    False (``out`` untouched) where the prior or the posterior has no inverse."""
    n = idx.size
    try:  # (the inverses as the update makes them: written out below, no other routine to compile)
        info = information(P_prior, idx)
        posterior = _inverse(A)
    except Exception:  # noqa: BLE001 - numba's linear algebra raises its one kind
        return False
    spread = np.zeros((n, n))  # P⁺Λ
    for i in range(n):
        for k in range(n):
            pik = posterior[i, k]
            for j in range(n):
                spread[i, j] += pik * info[k, j]
    cov = info.copy()
    g = np.zeros(n)
    for i in range(n):
        for k in range(n):
            lik = info[i, k]
            g[i] += lik * (s[idx[k]] - s_prior[idx[k]])
            for j in range(n):
                cov[i, j] -= lik * spread[k, j]
    for f in range(families.shape[0]):
        kind, i, j = families[f, 0], families[f, 1], families[f, 2]
        statistic = 0.0
        if kind == 0:
            if cov[i, i] > 0.0:
                statistic = g[i] * g[i] / cov[i, i]
        elif kind == 1:
            a, b, d = cov[i, i], cov[i, j], cov[j, j]
            det = a * d - b * b
            if det > 0.0:
                statistic = (d * g[i] * g[i] - 2.0 * b * g[i] * g[j] + a * g[j] * g[j]) / det
        else:
            gd = g[j] + dt * g[i]
            cd = cov[j, j] + 2.0 * dt * cov[i, j] + dt * dt * cov[i, i]
            if cd > 0.0:
                statistic = gd * gd / cd
        out[f] = statistic
    return True


def agreement(y: np.ndarray, weight: np.ndarray, values: np.ndarray, half: int, offset0: float, cap: float,
              rounds: int, cost: np.ndarray, gain_out: np.ndarray, offset_out: np.ndarray) -> None:
    """At each position (a row of ``values``: the model's values there) how well the frame's samples agree
    (filter._agreement): the light the agreeing samples share — each sample's gain against the model (less
    ``offset0``), the shortest span holding ``half`` of them, its middle — then gain and offset fitted to the
    samples within the per-sample test (χ² below ``cap``), ``rounds`` times; ``cost`` the samples' χ² each
    capped at ``cap`` (inf where no light is found), with the light into ``gain_out`` and ``offset_out``."""
    n_grid, n = values.shape
    ratio = np.empty(n)
    for g in range(n_grid):
        cost[g] = np.inf
        m = 0
        for p in range(n):
            if weight[p] > 0.0 and values[g, p] > 0.0:
                ratio[m] = (y[p] - offset0) / values[g, p]
                m += 1
        if m < half or half < 1:
            continue
        ordered = np.sort(ratio[:m])
        first, narrowest = 0, np.inf
        for i in range(m - half + 1):
            span = ordered[i + half - 1] - ordered[i]
            if span < narrowest:
                first, narrowest = i, span
        gain = 0.5 * (ordered[first] + ordered[first + half - 1])
        offset = offset0
        found = True
        for _ in range(rounds):
            s1 = sy = sf = sff = syf = 0.0
            for p in range(n):
                w = weight[p]
                if w <= 0.0:
                    continue
                v = values[g, p]
                r = y[p] - gain * v - offset
                if r * r * w < cap:
                    s1 += w
                    sy += w * y[p]
                    sf += w * v
                    sff += w * v * v
                    syf += w * v * y[p]
            det = sff * s1 - sf * sf
            if not det > 0.0:
                found = False
                break
            gain = (syf * s1 - sf * sy) / det
            offset = (sff * sy - sf * syf) / det
        if not found or not gain > 0.0:
            continue
        total = 0.0
        for p in range(n):
            w = weight[p]
            if w <= 0.0:
                continue
            r = y[p] - gain * values[g, p] - offset
            c = r * r * w
            total += c if c < cap else cap
        cost[g], gain_out[g], offset_out[g] = total, gain, offset


def row_mean(frame: np.ndarray, out: np.ndarray) -> float:
    """``out`` (n,): the mean of ``frame``'s rows (R, n) in float64, summed row after row and divided by
    R: what the model's ``prepare`` computes with numpy, to the bit, without its arrays made a frame.
    Returns the sum of ``out``: not finite where a sample is not (a float camera's dead pixel)."""
    n_rows, n = frame.shape
    for p in range(n):
        out[p] = frame[0, p]
    for r in range(1, n_rows):
        for p in range(n):
            out[p] += frame[r, p]
    if n_rows > 1:
        for p in range(n):
            out[p] = out[p] / n_rows
    total = 0.0
    for p in range(n):
        total += out[p]
    return total


def rows_clipped(frame: np.ndarray, lo: float, hi: float, y: np.ndarray) -> None:
    """In place: ``y``, the mean of ``frame``'s rows (R, n), at the sensor's limit wherever a row's sample sits
    at it (a mean over a clipped sample is biased by the clip: its column carries no position either)."""
    n_rows, n = frame.shape
    for p in range(n):
        for r in range(n_rows):
            v = frame[r, p]
            if v >= hi:
                y[p] = hi
                break
            if v <= lo:
                y[p] = lo
                break


def in_range(y: np.ndarray, lo: float, hi: float, mask: np.ndarray, out: np.ndarray) -> None:
    """``out``: ``mask`` where ``y`` lies strictly between the sensor's limits, 0 elsewhere."""
    for p in range(y.size):
        out[p] = mask[p] * (1.0 if (y[p] > lo) & (y[p] < hi) else 0.0)


def predict(s: np.ndarray, P: np.ndarray, dt: float, q_held: float, q_white: float, rates2: np.ndarray,
            flicker: np.ndarray) -> None:
    """In place: the state and covariance moved on by ``dt`` s: constant velocity with an acceleration of
    variance ``q_held`` (mm²/s⁴) held over the interval (a commanded phase: the discrete model) and one of
    variance ``q_white`` white within it (the stage's own wandering: the continuous model, of the same velocity
    variance q·dt² over the interval); every other state a random walk of variance ``rates2`` per second. The
    frame's light (the gain) moved on by the lamp's flicker: ``flicker`` the change over the interval of the
    cosine and the sine of twice the mains's phase, and their values at the new time."""
    n = s.size
    if P[FC, FC] > 0.0 or P[FS, FS] > 0.0:
        # The gain is the lamp's mean light plus the flicker's parts times the cosine and the sine at the frame's
        # time: g⁺ = g + Δcos·f_c + Δsin·f_s (P ← F P Fᵀ), and each part's own walk w moves the new frame's light by
        # its cosine or sine times w.
        d_cos, d_sin, cos_new, sin_new = flicker[0], flicker[1], flicker[2], flicker[3]
        s[G] += d_cos * s[FC] + d_sin * s[FS]
        for j in range(n):
            P[G, j] += d_cos * P[FC, j] + d_sin * P[FS, j]
        for i in range(n):
            P[i, G] += d_cos * P[i, FC] + d_sin * P[i, FS]
        # (each part walks by its rate relative to the flicker's depth: a flicker's phase turns with the grid's
        # frequency and its depth with the lamp, a lamp without one holds none, whatever the camera's frame rate)
        q_cos = q_sin = 0.5 * rates2[FC] * dt * (s[FC] * s[FC] + s[FS] * s[FS])
        P[FC, FC] += q_cos
        P[FS, FS] += q_sin
        P[G, FC] += cos_new * q_cos
        P[FC, G] += cos_new * q_cos
        P[G, FS] += sin_new * q_sin
        P[FS, G] += sin_new * q_sin
        P[G, G] += cos_new * cos_new * q_cos + sin_new * sin_new * q_sin
    # The carriage is its path plus the last frame's jitter D: the path moves on at its velocity, the jitter is
    # drawn afresh (variance rates2[D], white, not a walk): x⁺ = x + v·dt − d + d⁺, d⁺ new.
    s[X] += s[V] * dt - s[D]
    s[D] = 0.0
    # P ← F P Fᵀ with F = I + dt·e_X e_Vᵀ − e_X e_Dᵀ, then the jitter's row and column anew
    for j in range(n):
        P[X, j] += dt * P[V, j] - P[D, j]
    for i in range(n):
        P[i, X] += dt * P[i, V] - P[i, D]
    for i in range(n):
        P[i, D] = 0.0
        P[D, i] = 0.0
    dt2 = dt * dt
    # An acceleration held over the interval ties the velocity's change to the position's wholly (correlation 1): where
    # the frames read the position far better than that acceleration moves it (the grating fused, no path held), the
    # velocity was then twice the last step's less the one before, and its error rang from frame to frame at half
    # the frame rate without ever decaying (±0.4 mm/s at 1 mm/s, the position's bound with it on alternate frames).
    # One white within the interval leaves a quarter of the velocity's change unread by the positions (correlation
    # √3/2), and the ringing halves from frame to frame.
    P[X, X] += (q_held / 4.0 + q_white / 3.0) * dt2 * dt2 + rates2[D]
    P[X, V] += (q_held + q_white) * dt2 * dt / 2.0
    P[V, X] += (q_held + q_white) * dt2 * dt / 2.0
    P[V, V] += (q_held + q_white) * dt2
    P[X, D] = P[D, X] = P[D, D] = rates2[D]
    for pair in range(_DRIFTS.shape[0]):
        # a state drifting at its rate, which itself changes white (the latch at the clocks' rates apart, the blur as
        # a lens warms): x⁺ = x + r·dt, P ← F P Fᵀ + Q with Q the integrated random walk's
        i_x, i_r = _DRIFTS[pair, 0], _DRIFTS[pair, 1]
        if not P[i_r, i_r] > 0.0:  # (not a state of this estimator: held at zero)
            continue
        s[i_x] += s[i_r] * dt
        for j in range(n):
            P[i_x, j] += dt * P[i_r, j]
        for i in range(n):
            P[i, i_x] += dt * P[i, i_r]
        q = rates2[i_r]
        P[i_x, i_x] += q * dt2 * dt / 3.0
        P[i_x, i_r] += q * dt2 / 2.0
        P[i_r, i_x] += q * dt2 / 2.0
        P[i_r, i_r] += q * dt
    if s[BE] > 0.0:  # a band in view: its two edges move together at its speed, whose change is white
        # (rates2[BW] its acceleration's variance, as the stage's); out of view its states are held at zero
        s[BL] += s[BW] * dt
        s[BR] += s[BW] * dt
        for j in range(n):
            P[BL, j] += dt * P[BW, j]
            P[BR, j] += dt * P[BW, j]
        for i in range(n):
            P[i, BL] += dt * P[i, BW]
            P[i, BR] += dt * P[i, BW]
        q_band = rates2[BW]
        for i in (BL, BR):
            for j in (BL, BR):
                P[i, j] += q_band * dt2 * dt2 / 4.0
            P[i, BW] += q_band * dt2 * dt / 2.0
            P[BW, i] += q_band * dt2 * dt / 2.0
        P[BW, BW] += q_band * dt2
        for i in (BD, BL, BR, BE, BH):
            P[i, i] += rates2[i] * dt
    for i in range(n):
        if i != X and i != V and i < BD:
            P[i, i] += rates2[i] * dt


def _band(u: float, left: float, right: float, edge: float) -> float:
    """The band's profile B at target coordinate ``u`` (1 in its core, 0 far from it)."""
    scale = 1.0 / (ROOT_2 * edge)
    return 0.5 * (math.erf((u - left) * scale) - math.erf((u - right) * scale))


def _evaluate(x: float, model: tuple, values: np.ndarray, slopes: np.ndarray, smooth: np.ndarray) -> None:
    kernels._evaluate_into(x, *model, values, slopes, smooth)


def _normal(s: np.ndarray, idx: np.ndarray, y: np.ndarray, w: np.ndarray, rho: np.ndarray, values: np.ndarray,
            slopes: np.ndarray, curvature: np.ndarray, t_rel: np.ndarray, r_rel: np.ndarray, b1: np.ndarray,
            b2: np.ndarray, half_d2: float, A: np.ndarray, rhs: np.ndarray, residual: np.ndarray,
            row_len: int = 0, row_precision: float = 0.0) -> float:
    """The normal matrix and right-hand side of the frame's samples over the active states; the
    residuals into ``residual``; returns Σρw r². With ``row_precision`` (1/σ² of an offset each row of
    ``row_len`` samples draws afresh every frame, gray⁻²: a sensor's row banding), each row's offset is
    eliminated from the equations (their Schur complement: what the row's own mean level says is its
    offset's, as far as its prior allows), the cost counts its prior, and the residuals are left without it."""
    n = idx.size
    for i in range(n):
        rhs[i] = 0.0
        for j in range(n):
            A[i, j] = 0.0
    rows = row_precision > 0.0 and row_len > 0
    u = np.zeros(n)  # the row's Σρw·Jacobian, Σρw and Σρw·r
    row_w, row_q, row_start = 0.0, 0.0, 0
    jac = np.zeros(N_STATE)  # (a dozen numbers a solve: numba keeps them on the stack)
    active = np.empty(n)  # the Jacobian over the active states, and weighted
    weighted = np.empty(n)
    g, o, a1, a2, b, m, th = s[G], s[OFS], s[A1], s[A2], s[B], s[M], s[T]
    lever = s[L]
    depth, left, right, edge, haze = s[BD], s[BL], s[BR], s[BE], s[BH]
    banded = edge > 0.0  # a band in view (its states in the state only then)
    inv_edge = 1.0 / edge if banded else 0.0
    cost = 0.0
    for p in range(y.size + (1 if rows else 0)):
        if rows and p % row_len == 0 and p > 0:  # the last row's offset eliminated
            denom = row_w + row_precision
            offset = row_q / denom
            cost -= row_q * offset
            for i in range(n):
                rhs[i] -= u[i] * offset
                ui = u[i] / denom
                row = A[i]
                for j in range(n):
                    row[j] -= ui * u[j]
            for i in range(n):
                u[i] = 0.0
            for k in range(row_start, p):
                residual[k] -= offset
            row_w, row_q, row_start = 0.0, 0.0, p
        if p == y.size:
            break
        level0 = g + a1 * b1[p] + a2 * b2[p]
        shade, band, d_left, d_right, d_edge = 1.0, 0.0, 0.0, 0.0, 0.0
        if banded:
            zl = (t_rel[p] - left) * inv_edge
            zr = (t_rel[p] - right) * inv_edge
            band = 0.5 * (math.erf(zl / ROOT_2) - math.erf(zr / ROOT_2))
            pl = math.exp(-0.5 * zl * zl) / ROOT_2PI
            pr = math.exp(-0.5 * zr * zr) / ROOT_2PI
            d_left, d_right, d_edge = -pl * inv_edge, pr * inv_edge, (zr * pr - zl * pl) * inv_edge
            shade = 1.0 - depth * band
        level = level0 * shade
        f, df = values[p], slopes[p]
        ft = f + df * (m * t_rel[p] + th * r_rel[p]) + half_d2 * b * curvature[p]
        r = y[p] - (level * ft + o + haze * band)
        residual[p] = r
        weight = w[p] * rho[p]
        if weight <= 0.0:
            continue
        cost += weight * r * r
        gdf = level * df
        jac[X] = gdf
        jac[G] = shade * ft
        jac[OFS] = 1.0
        jac[A1] = b1[p] * shade * ft
        jac[A2] = b2[p] * shade * ft
        if banded:
            lost = haze - level0 * ft * depth  # what the band changes where its profile is 1
            jac[BD] = -level0 * ft * band
            jac[BL] = lost * d_left
            jac[BR] = lost * d_right
            jac[BE] = lost * d_edge
            jac[BH] = band
        jac[B] = level * half_d2 * curvature[p]
        jac[M] = gdf * (t_rel[p] + lever)
        jac[C] = gdf
        jac[L] = gdf * m
        jac[T] = gdf * r_rel[p]
        for i in range(n):
            active[i] = jac[idx[i]]
        for i in range(n):
            ji = weight * active[i]
            weighted[i] = ji
            rhs[i] += ji * r
        if rows:
            row_w += weight
            row_q += weight * r
            for i in range(n):
                u[i] += weighted[i]
        # Whole rows, the same products and sums element by element as the lower triangle alone (the
        # compiler vectorises a row); the upper triangle is then the lower's mirror, as it always was.
        for i in range(n):
            ji = weighted[i]
            row = A[i]
            for j in range(n):
                row[j] += ji * active[j]
    for i in range(n):
        for j in range(i):
            A[j, i] = A[i, j]
    return cost


def _grating(s: np.ndarray, v: float, idx: np.ndarray, z: float, weight: float, A: np.ndarray,
             rhs: np.ndarray) -> float:
    """The grating's reading z = x − v·τ (latched τ before mid-exposure) into the normal equations, ``v``
    the velocity the motion predicts (the latch's lever on the velocity is not a measurement of it: through a
    skew of tens of µs, a µm of the model's own error would read as mm/s, and the velocity rang ±7 mm/s
    frame to frame on a clean 200 fps run); returns its χ² term."""
    n = idx.size
    jac = np.zeros(n)
    for i in range(n):
        if idx[i] == X:
            jac[i] = 1.0
        elif idx[i] == SK:
            jac[i] = -v
    r = z - (s[X] - v * s[SK])
    for i in range(n):
        rhs[i] += weight * jac[i] * r
        for j in range(n):
            A[i, j] += weight * jac[i] * jac[j]
    return weight * r * r


def _reweigh(residual: np.ndarray, w: np.ndarray, rho: np.ndarray, core: float, cut: float, first: bool,
             apply: bool) -> bool:
    """Whether the redescending weights the residuals call for (Tukey's taper between ``core`` and ``cut`` robust
    σ of the normalised residuals, never below the noise model's) differ from ``rho`` by more than 1e-3 at a
    sample; with ``apply``, ``rho`` becomes them. ``first``: the weights are all 1 yet, and stay so while every
    normalised residual is within the core at the noise model's σ."""
    z = np.empty(residual.size)
    count = 0
    largest = 0.0
    for p in range(residual.size):
        if w[p] > 0.0:
            z[count] = abs(residual[p]) * math.sqrt(w[p])
            if z[count] > largest:
                largest = z[count]
            count += 1
    if count == 0 or (first and largest <= core):
        return False
    scale = MAD_TO_SIGMA * np.median(z[:count])
    if scale < 1.0:
        scale = 1.0
    changed = False
    for p in range(residual.size):
        if w[p] <= 0.0:
            continue
        u = abs(residual[p]) * math.sqrt(w[p]) / scale
        if u <= core:
            new = 1.0
        elif u >= cut:
            new = 0.0
        else:
            q = (u - core) / (cut - core)
            new = (1.0 - q * q) ** 2
        if abs(new - rho[p]) > 1e-3:
            changed = True
            if not apply:
                return True
        if apply:
            rho[p] = new
    return changed


def update(s: np.ndarray, s_prior: np.ndarray, P_prior: np.ndarray, idx: np.ndarray, y: np.ndarray, mask: np.ndarray,
           pixels: np.ndarray, params: np.ndarray, model: tuple, scratch: np.ndarray, rho: np.ndarray,
           A_out: np.ndarray, stats: np.ndarray, P_post: np.ndarray, sigma: np.ndarray) -> None:
    """Update ``s`` (in place, from ``s_prior``) with one frame.

    ``P_prior``: the prior covariance (its block over the active states ``idx`` is used, centred on
    ``s_prior``); with ``params[U_PREDICT]`` set, ``s_prior`` and ``P_prior`` are first moved on by
    ``params[U_DT]`` in place (:func:`predict`: the frame's two calls made one).
    ``pixels``: (4, P) by the PX_ constants; ``params``: the numbers named by the U_ constants.
    ``scratch``: (6, P); ``rho``: (P,) robust weights out; ``A_out``: the posterior information over
    ``idx``; ``stats``: the figures named by the S_ constants; with ``params[U_POSTERIOR]`` set, ``P_post`` the
    (predicted) prior with the posterior embedded and ``sigma`` every state's σ (:func:`embed`: the frame's
    next call made in this one), and with ``params[U_LIGHT]`` set too, the light's modes weighed on it into
    ``stats[S_LIGHT]`` (light_modes.py reweigh: another)."""
    t_rel, r_rel, b1, b2 = pixels[PX_TARGET], pixels[PX_ROW], pixels[PX_B1], pixels[PX_B2]
    read_var, shot_gain, dark = params[U_READ], params[U_SHOT], params[U_DARK]
    level = params[U_LEVEL]
    pitch_mm, period_mm = params[U_PITCH], params[U_PERIOD]
    grating_z, grating_w = params[U_GRATING_Z], params[U_GRATING_W]
    robust = params[U_ROBUST] > 0.0
    core, cut, tolerance = params[U_CORE], params[U_CUT], params[U_TOLERANCE]
    max_iterations = int(params[U_ITERATIONS])
    row_length, row_precision = int(params[U_ROW_LENGTH]), params[U_ROW_PRECISION]
    if params[U_PREDICT] > 0.0:
        predict(s_prior, P_prior, params[U_DT], params[U_ACCELERATION], params[U_ACCELERATION_WHITE], params[U_RATES:],
                params[U_FLICKER:U_RATES])
    warm = params[U_WARM] > 0.0  # from ``s`` and ``rho`` as passed, not the prior's mean and full weights
    sharpest = params[U_BAND_SHARPEST]
    banding = s_prior[BE] > 0.0  # (a band in view: its states solved)
    if not warm:
        for i in range(s.size):
            s[i] = s_prior[i]
    n = idx.size
    Pinv = information(P_prior, idx)
    values, slopes, smooth, curvature, w, residual = (scratch[0], scratch[1], scratch[2], scratch[3], scratch[4],
                                                      scratch[5])
    xi = s[X] + s[C] + s[L] * s[M] + params[U_MAPPED]
    step = CURVATURE_STEP_PERIODS * period_mm
    _evaluate(xi + step, model, values, curvature, smooth)
    _evaluate(xi, model, values, slopes, smooth)
    half_d2 = 0.5 * pitch_mm * pitch_mm
    for p in range(y.size):
        curvature[p] = (curvature[p] - slopes[p]) / step
        # the noise model's weight at the predicted gray value
        gray = (s[G] + s[A1] * b1[p] + s[A2] * b2[p]) * values[p] + s[OFS]
        if s[BE] > 0.0:
            band = _band(t_rel[p], s[BL], s[BR], s[BE])
            gray = (gray - s[OFS]) * (1.0 - s[BD] * band) + s[OFS] + s[BH] * band
        signal = gray - dark
        if signal < 0.0:
            signal = 0.0
        var = read_var + shot_gain * signal
        if var < 1e-6:
            var = 1e-6
        w[p] = mask[p] / (var * level)
        if not warm:
            rho[p] = 1.0
    A = np.zeros((n, n))
    bare = np.zeros((n, n))  # the samples' normal matrix alone, before the prior and the grating
    rhs = np.zeros(n)
    delta = np.zeros(n)
    factor = np.zeros((n, n))  # (the normal matrix's Cholesky factor, each step's)
    total_iterations = 0
    converged = 0.0
    cost = 0.0
    for round_ in range(ROBUST_ROUNDS + 1):
        at = xi
        fresh = False
        for it in range(max_iterations):
            total_iterations += 1
            xi = s[X] + s[C] + s[L] * s[M] + params[U_MAPPED]
            if xi != at:
                _evaluate(xi, model, values, slopes, smooth)
                at = xi
            cost = _normal(s, idx, y, w, rho, values, slopes, curvature, t_rel, r_rel, b1, b2, half_d2, A, rhs,
                           residual, row_length, row_precision)
            if robust and it > 0 and round_ < ROBUST_ROUNDS and _reweigh(residual, w, rho, core, cut, round_ == 0,
                                                                          False):
                # where the first step has taken the frame the weights already differ from this round's: they
                # are reweighted from here, not after converging on weights about to change (each round to 1 nm)
                fresh = True
                break
            bare[:, :] = A
            for i in range(n):
                acc = 0.0
                for j in range(n):
                    acc += Pinv[i, j] * (s[idx[j]] - s_prior[idx[j]])
                    A[i, j] += Pinv[i, j]
                rhs[i] -= acc
            if grating_w > 0.0:
                _grating(s, s_prior[V], idx, grating_z, grating_w, A, rhs)
            _solve(A, rhs, delta, factor)
            moved = 0.0
            for i in range(n):
                s[idx[i]] += delta[i]
            if banding and s[BE] < sharpest:
                # A band barely in view tells its penumbra little, and a full step can take its σ through nought,
                # where the band vanishes from the model and the next step, seeing only its prior, undoes this
                # one (the solve then swings between the two): the step is taken to the bound instead.
                s[BE] = sharpest
            for i in range(n):
                if idx[i] == X or idx[i] == C:
                    moved += abs(delta[i])
            if moved <= tolerance:
                converged = 1.0
                break
        if converged > 0.0:
            # the last step was below the tolerance: the model there is the model here, to far below any bound
            A[:, :] = bare
        elif not fresh:  # (fresh: the residuals are this state's already)
            xi = s[X] + s[C] + s[L] * s[M] + params[U_MAPPED]
            if xi != at:
                _evaluate(xi, model, values, slopes, smooth)
            cost = _normal(s, idx, y, w, rho, values, slopes, curvature, t_rel, r_rel, b1, b2, half_d2, A, rhs,
                           residual, row_length, row_precision)
        if not robust or not _reweigh(residual, w, rho, core, cut, round_ == 0, True):
            break
        converged = 0.0  # the weights moved: solved again from here
        if round_ == ROBUST_ROUNDS:
            cost = _normal(s, idx, y, w, rho, values, slopes, curvature, t_rel, r_rel, b1, b2, half_d2, A, rhs,
                           residual, row_length, row_precision)
    conditioned(s, s_prior, P_prior, idx, Pinv, stats[S_GAIN:])
    # the posterior information (normal matrix with the prior and the grating) and the figures
    prior = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            A[i, j] += Pinv[i, j]
            acc += Pinv[i, j] * (s[idx[j]] - s_prior[idx[j]])
        prior += (s[idx[i]] - s_prior[idx[i]]) * acc
    grating_cost = 0.0
    if grating_w > 0.0:
        grating_cost = _grating(s, s_prior[V], idx, grating_z, grating_w, A, rhs)
    A_out[:, :] = A
    used = 0.0
    rejected = 0.0
    weighed = 0.0
    xinfo = 0.0
    rss = 0.0
    level_g = s[G]
    for p in range(y.size):
        if mask[p] <= 0.0:
            continue
        if rho[p] <= 0.0:
            rejected += 1.0
            continue
        if rho[p] < 1.0:
            weighed += 1.0
        used += 1.0
        rss += residual[p] * residual[p]
        gdf = (level_g + s[A1] * b1[p] + s[A2] * b2[p]) * slopes[p]
        if s[BE] > 0.0:
            gdf *= 1.0 - s[BD] * _band(t_rel[p], s[BL], s[BR], s[BE])
        xinfo += w[p] * rho[p] * gdf * gdf
    stats[S_COST] = cost + prior + grating_cost
    stats[S_RESIDUAL] = cost
    stats[S_PRIOR] = prior
    stats[S_USED] = used
    stats[S_REJECTED] = rejected
    stats[S_ITER] = total_iterations
    stats[S_XINFO] = xinfo
    stats[S_RMS] = math.sqrt(rss / used) if used > 0 else math.nan
    stats[S_GRATING] = grating_cost
    stats[S_CONVERGED] = converged
    stats[S_POSTERIOR] = 0.0
    stats[S_WEIGHED] = weighed
    if params[U_POSTERIOR] > 0.0:
        # made on the chance the frame is kept: an update that failed (its information not finite, or
        # singular) is no error here, the frame is refused by its figures and its covariance not made
        try:
            P_post[:, :] = P_prior
            embed(P_post, A_out, idx, sigma, stats[S_GAIN:])
            stats[S_POSTERIOR] = 1.0
        except Exception:  # noqa: BLE001 - numba's linear algebra raises its one kind
            pass
        if stats[S_POSTERIOR] > 0.0 and params[U_LIGHT] > 0.0:
            stats[S_LIGHT] = reweigh(P_prior, P_post, s_prior, s, G, OFS, params[U_LIGHT + 1], params[U_LIGHT + 2],
                                     params[U_LIGHT + 3] > 0.0, params[U_LIGHT + 4])


def residuals(s: np.ndarray, y: np.ndarray, mask: np.ndarray, rho: np.ndarray, pixels: np.ndarray,
              params: np.ndarray, model: tuple, scratch: np.ndarray, noise_var: np.ndarray) -> None:
    """Each sample's residual against the state ``s`` (y − h(s), into ``scratch[5]``) and the noise model's
    variance at h (one sample's, before a mask's weight) into ``noise_var``: what a frame left per sample,
    for the maps (sensor_map.py, print_map.py). Where each row draws an offset afresh every frame (a sensor's row
    banding: ``params[U_ROW_PRECISION]``), it is taken out of the row's residuals as the update takes it (_normal:
    the residuals' weighted sum over the row's weights and the offset's precision, each sample weighed by ``mask``
    and its robust weight ``rho`` over its noise at the calibration's level): what the row shares that frame is no
    sample's own, and left in, a row's offset beyond the noise landed its samples on the maps."""
    t_rel, r_rel, b1, b2 = pixels[PX_TARGET], pixels[PX_ROW], pixels[PX_B1], pixels[PX_B2]
    pitch_mm, period_mm = params[U_PITCH], params[U_PERIOD]
    values, slopes, smooth, curvature, residual = scratch[0], scratch[1], scratch[2], scratch[3], scratch[5]
    xi = s[X] + s[C] + s[L] * s[M] + params[U_MAPPED]
    step = CURVATURE_STEP_PERIODS * period_mm
    _evaluate(xi + step, model, values, curvature, smooth)
    _evaluate(xi, model, values, slopes, smooth)
    for p in range(y.size):
        curvature[p] = (curvature[p] - slopes[p]) / step
    none = np.empty(0, dtype=np.int64)  # no state: the normal equations are empty, the residuals made
    _normal(s, none, y, np.zeros(y.size), np.zeros(y.size), values, slopes, curvature, t_rel, r_rel, b1, b2,
            0.5 * pitch_mm * pitch_mm, np.zeros((0, 0)), np.zeros(0), residual)
    read_var, shot_gain, dark = params[U_READ], params[U_SHOT], params[U_DARK]
    for p in range(y.size):
        signal = y[p] - residual[p] - dark
        var = read_var + shot_gain * (signal if signal > 0.0 else 0.0)
        noise_var[p] = var if var > 1e-6 else 1e-6  # (the update's own floor)
    row_len, precision, level = int(params[U_ROW_LENGTH]), params[U_ROW_PRECISION], params[U_LEVEL]
    if precision > 0.0 and row_len > 0 and level > 0.0:
        for start in range(0, y.size, row_len):
            stop = min(start + row_len, y.size)
            total, weighted = 0.0, 0.0
            for p in range(start, stop):
                weight = mask[p] * rho[p] / (noise_var[p] * level)
                total += weight
                weighted += weight * residual[p]
            offset = weighted / (total + precision)
            for p in range(start, stop):
                residual[p] -= offset


def longest_run(scaled: np.ndarray, width: int, sign: float) -> float:
    """The longest run of samples beyond one on the side ``sign`` (``sign · scaled > 1``) along any row of
    ``width`` samples (a single sample within between two beyond bridged: a sample on a mark's slope that
    happened to pass); a run that reaches either end of its row over half the narrowest band's width (a
    twelfth of the row) is a band's edge entering, as long as any (infinite)."""
    longest = 0.0
    reach = width / 12.0
    for first in range(0, scaled.size - width + 1, width):
        run, gap = 0, 0
        for p in range(width):
            if sign * scaled[first + p] > 1.0:
                run, gap = run + 1 + gap, 0
                if run >= reach and (p == width - 1 or run == p + 1):
                    return math.inf
            elif run and gap == 0:
                gap = 1
            else:
                run, gap = 0, 0
            if run > longest:
                longest = run
    return longest


if kernels.COMPILED:
    _jit = kernels.numba.njit(cache=True, nogil=True, error_model="numpy")
    predict = _jit(predict)
    _cholesky = _jit(_cholesky)
    _inverse = _jit(_inverse)
    _solve = _jit(_solve)
    information = _jit(information)
    conditioned = _jit(conditioned)
    embed = _jit(embed)
    scores = _jit(scores)
    carried = _jit(carried)
    agreement = _jit(agreement)
    longest_run = _jit(longest_run)
    row_mean = _jit(row_mean)
    in_range = _jit(in_range)
    rows_clipped = _jit(rows_clipped)
    _evaluate = _jit(_evaluate)
    _band = _jit(_band)
    _normal = _jit(_normal)
    _grating = _jit(_grating)
    _reweigh = _jit(_reweigh)
    update = _jit(update)
    residuals = _jit(residuals)
