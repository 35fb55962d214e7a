"""Compiled loops of the validity watches over many frames (batch tracking, ``track``'s scale check).

Each watch's state runs frame by frame (running averages, a sliding window): these loops are the
watches' own ``step`` transcribed operation for operation, so they give the same numbers, bit for
bit (tests/core/test_watch_kernels.py runs both on the same frames). Python's ``min``/``max`` are
spelt out (:func:`_min`, :func:`_max`: which argument wins on a tie or a NaN), squares are
products on both sides, and constants the Python code squares are squared in Python and passed in.

numba compiles them on first use (cached on disk next to this file); without numba, or with
``GRAYTRACK_KERNEL=numpy``, :data:`COMPILED` is False and the watches step frame by frame in Python.
"""

from __future__ import annotations

import math


from graytrack.core.kernels import COMPILED, numba

# the reference monitor's stops (what _reference_run returns next to the frame it stopped at)
DONE, RECOMPUTE, ROSE = 0, 1, 2


def _max(a: float, b: float) -> float:
    """Python's ``max(a, b)``: ``a`` unless ``b > a``."""
    return b if b > a else a


def _min(a: float, b: float) -> float:
    """Python's ``min(a, b)``: ``a`` unless ``b < a``."""
    return b if b < a else a


def _running(average: float, has: bool, value: float, window: float) -> float:
    """core/validity.py's ``running`` (``has`` False: the average is None)."""
    if not has or not math.isfinite(average):
        return value
    return average + (value - average) / window


# ---------------------------------------------------------------- the reference monitor (scale)
def slide_window(sums, w: float, d: float, r: float, new_place: float, ow: float, od: float, o_r: float,
                 o_place: float) -> None:
    """One frame (weight, place, residual, new grating place) into the window's sums
    [Σw, Σwd, Σwd², Σwr, Σwrd, Σwr², places] and the frame (ow, od, o_r, o_place) out of them (all
    zero while none leaves: the same sums to the bit). A list for the monitor frame by frame, an
    array in the compiled run: one arithmetic for both."""
    wd, wr = w * d, w * r
    owd, owr = ow * od, ow * o_r
    sums[0] += w - ow
    sums[1] += wd - owd
    sums[2] += wd * d - owd * od
    sums[3] += wr - owr
    sums[4] += wr * d - owr * od
    sums[5] += wr * r - owr * o_r
    sums[6] += new_place - o_place


slide_window_python = slide_window  # the monitor's frame-by-frame path (a list; the compiled one takes arrays)


# ip: window, min_frames, outlier run that restarts the window, calibration_frames, recompute every,
#     update every
# p: center_mm, half_stroke_mm, reference_sigma_mm, place tolerance, floor (µm), z_on², z_off², prior
#    weight, 1/prior weight, (reference σ in µm)², structure², calibration_x_std_mm,
#    baseline (has, offset, scale, cov×3), calibration (has, offset, scale, cov×3)
# ist: count, next, since_recompute, outliers, fed, stale, has estimate
# fst: Σw, Σwd, Σwd², Σwr, Σwrd, Σwr², places, scatter, last reference, significance
# est: offset, scale, cov×3, center, frames, mean


def _chi2_per_dof(fst, count, a, b):
    sw, swd, swdd, swr, swrd, swrr = fst[0], fst[1], fst[2], fst[3], fst[4], fst[5]
    chi2 = swrr - 2 * a * swr - 2 * b * swrd + a * a * sw + 2 * a * b * swd + b * b * swdd
    den = count - 2
    if 1 > den:
        den = 1
    return _max(chi2, 0.0) / den


def _update(ip, p, ist, fst, est):
    count = ist[0]
    if count < ip[1]:
        return
    # _fit
    sw, swd, swdd, swr, swrd = fst[0], fst[1], fst[2], fst[3], fst[4]
    prior = p[7]
    base_scale = (p[14] if p[12] != 0.0 else 0.0) * 1e-3
    n11, n12, n22 = sw, swd, swdd + prior
    r1, r2 = swr, swrd + prior * base_scale
    det = n11 * n22 - n12 * n12
    offset = (n22 * r1 - n12 * r2) / det
    slope = (n11 * r2 - n12 * r1) / det
    fst[7] = _max(_chi2_per_dof(fst, count, offset, slope), 1.0)
    inflate = fst[7] / det
    # _rounding_covariance
    sigma2 = p[9]
    if sigma2 == 0.0:
        ro0, ro1, ro2 = 0.0, 0.0, 0.0
    else:
        places = _max(fst[6], 1.0)
        mean = swd / sw
        spread2 = _max(swdd / sw - mean * mean, 0.0)
        var_s = sigma2 / (places * spread2) if spread2 > 0 else math.inf
        var_s = _min(var_s, p[8])
        ro0, ro1, ro2 = sigma2 / places + mean * mean * var_s, -mean * var_s, var_s
    est[0] = offset
    est[1] = slope * 1e3
    est[2] = n22 * inflate + ro0
    est[3] = (-n12 * inflate + ro1) * 1e3
    est[4] = (n11 * inflate + ro2) * 1e6
    est[5] = p[0]
    est[6] = count
    est[7] = p[0] + swd / sw
    ist[6] = 1
    # the drift against the baseline (the trim in force), else the calibration's line
    if p[12] != 0.0:
        has_base, b_off, b_scale, b0, b1, b2 = True, p[13], p[14], p[15], p[16], p[17]
    elif p[18] != 0.0:
        has_base, b_off, b_scale, b0, b1, b2 = True, p[19], p[20], p[21], p[22], p[23]
    else:
        has_base, b_off, b_scale, b0, b1, b2 = False, 0.0, 0.0, 0.0, 0.0, 0.0
    do = est[0] - (b_off if has_base else 0.0)
    ds = est[1] - (b_scale if has_base else 0.0)
    meaningful = abs(do) + abs(ds) * 1e-3 * p[1] >= p[4]
    if has_base:
        ref0, ref1, ref2 = b0, b1, b2
    else:  # _calibration_covariance
        k, spread = ip[3], p[11]
        if k < 3 or not spread > 0:
            ref0, ref1, ref2 = est[2], est[3], est[4]
        else:
            var = count / fst[0] * _max(_chi2_per_dof(fst, count, est[0], est[1] * 1e-3), 1.0)
            ref0, ref1, ref2 = var / k, 0.0, var / (k * spread * spread) * 1e6
    # _structure_covariance
    struct2 = p[10]
    if struct2 == 0.0:
        st0, st1, st2 = 0.0, 0.0, 0.0
    else:
        q = swd / sw
        half2 = 3.0 * _max(swdd / sw - q * q, 0.0)
        var_s = _min(struct2 / half2 if half2 > 0 else math.inf, p[8])
        st0, st1, st2 = struct2 + q * q * var_s, -q * var_s * 1e3, var_s * 1e6  # about the centre
    # _chi2
    a, b, c = est[2] + (ref0 + st0), est[3] + (ref1 + st1), est[4] + (ref2 + st2)
    det2 = a * c - b * b
    fst[9] = (c * do * do - 2 * b * do * ds + a * ds * ds) / det2 if det2 > 0 else 0.0
    ist[5] = 1 if meaningful and fst[9] >= (p[6] if ist[5] != 0 else p[5]) else 0


def _reset(ist, fst, rows):
    """ReferenceMonitor.reset keeping the baseline and the flag (a jump restarts the window)."""
    rows[:, :] = 0.0
    for i in range(6):
        fst[i] = 0.0
    fst[6], fst[8], fst[7] = 0.0, math.nan, 1.0
    ist[0] = ist[1] = ist[2] = ist[3] = 0
    ist[6] = 0
    fst[9] = 0.0


def _reference_run(ip, p, ist, fst, est, rows, x, ref, bound, feed, stale, scatter, start, stop_on_rise, lines):
    """ReferenceMonitor.observe of frames ``start:`` where ``feed`` (the flag after each into
    ``stale``, the window's scatter before each into ``scatter``, the line after each into ``lines``
    when it has a row a frame: whether there is one, its scale and the scale's variance); stops early
    at (frame, RECOMPUTE)
    once a frame's addition asks for the window to be re-summed (numpy's sums: Python does that and
    the rest of the frame), or at (frame + 1, ROSE) after the flag rose, with ``stop_on_rise``."""
    n = x.size
    window, min_frames, out_limit, every, update_every = ip[0], ip[1], ip[2], ip[4], ip[5]
    for i in range(start, n):
        before = ist[5]
        scatter[i] = fst[7]
        xm, rm, bm = x[i], ref[i], bound[i]
        if feed[i] and math.isfinite(xm) and math.isfinite(rm) and math.isfinite(bm) and bm > 0:
            d = rm - p[0]
            r = (xm - rm) * 1e3
            var = (bm * bm + p[2] * p[2]) * 1e6
            outlier = False
            if ist[6] != 0:  # _is_outlier
                dd = d * 1e-3
                spread = var * fst[7] + est[2] + 2 * dd * est[3] + dd * dd * est[4]
                e = r - est[0] - est[1] * dd
                if e * e <= 64.0 * spread:
                    ist[3] = 0
                else:
                    ist[3] += 1
                    if ist[3] < out_limit:
                        outlier = True
                    else:
                        _reset(ist, fst, rows)
            if not outlier:
                new_place = 0.0 if abs(rm - fst[8]) < p[3] else 1.0
                fst[8] = rm
                # _add
                w = 1.0 / var
                slot = ist[1]
                if ist[0] == window:
                    slide_window(fst, w, d, r, new_place, rows[slot, 0], rows[slot, 1], rows[slot, 2], rows[slot, 3])
                else:
                    ist[0] += 1
                    slide_window(fst, w, d, r, new_place, 0.0, 0.0, 0.0, 0.0)
                rows[slot, 0], rows[slot, 1], rows[slot, 2], rows[slot, 3] = w, d, r, new_place
                ist[1] = (slot + 1) % window
                ist[2] += 1
                if ist[2] >= every:  # the window is re-summed (by numpy, in Python), then the frame finished
                    return i, RECOMPUTE
                ist[4] += 1
                if ist[4] % update_every == 0 or ist[0] == min_frames or ist[5] != 0:
                    _update(ip, p, ist, fst, est)
        stale[i] = ist[5] != 0
        if lines.shape[0] > 0:  # the estimate after the frame (Python's Line: none, or its scale and variance)
            has = ist[6] != 0
            lines[i, 0], lines[i, 1], lines[i, 2] = (1.0, est[1], est[4]) if has else (0.0, 0.0, 0.0)
        if stop_on_rise and ist[5] != 0 and before == 0:
            return i + 1, ROSE
    return n, DONE


# ---------------------------------------------------------------- the small watches

def _grating_run(state, has, placed, reference, x, information, chi2, suspect, chi2_limit, scale2, window_max, settle,
                 limit2, gate2, out):
    """GratingWatch.step over frames: state (mean, square, bound², count), has (mean, square, bound²)."""
    mean, square, bound2, count = state[0], state[1], state[2], int(state[3])
    for i in range(x.size):
        if placed[i] and math.isfinite(reference[i]) and math.isfinite(x[i]) and information[i] > 0:
            difference = x[i] - reference[i]
            beyond = False
            if count >= settle and has[2] and bound2 != 0.0:  # GratingWatch._gated
                deviation = difference - mean
                gate = gate2 * (_max(_max(square - mean * mean, 0.0), bound2) + scale2 / information[i])
                if not deviation * deviation <= gate:
                    difference = mean + (math.sqrt(gate) if deviation > 0 else -math.sqrt(gate))
                    beyond = True
            if not (suspect[i] or (beyond and chi2[i] > chi2_limit)):  # else the images judge this frame
                count += 1
                window = count if count < window_max else window_max
                mean = _running(mean, has[0], difference, window)
                square = _running(square, has[1], difference * difference, window)
                bound2 = _running(bound2, has[2], scale2 / information[i], window)
                has[0] = has[1] = has[2] = True
            if beyond:
                out[i] = True
                continue
        if count < settle or not has[2] or bound2 == 0.0:
            out[i] = False
            continue
        spread2 = _max(square - mean * mean, 0.0)
        out[i] = not spread2 <= limit2 * bound2
    state[0], state[1], state[2], state[3] = mean, square, bound2, count


def _light_run(state, placed, free_light, gain, window, lo, hi, out):
    """LightWatch.step over frames: state (has gain, gain)."""
    has, average = state[0] != 0.0, state[1]
    for i in range(gain.size):
        if not (placed[i] and free_light[i]):
            if has:
                average = _running(average, True, 1.0, window)
            out[i] = False
            continue
        average = _running(average, has, gain[i], window)
        has = True
        out[i] = not (lo < average < hi)
    state[0], state[1] = 1.0 if has else 0.0, average


def _transient_run(state, placed, transient_px, at, frame, window, start_frame, share_stale, share_clear,
                   fixed_spread, out):
    """TransientWatch.step over frames: state (share, place, place², has ×3, blamed: 0 none,
    1 transients, 2 light); out: the family code after each frame."""
    share, place, place_sq = state[0], state[1], state[2]
    has_share, has_place, has_sq, blamed = state[3] != 0.0, state[4] != 0.0, state[5] != 0.0, int(state[6])
    for i in range(transient_px.size):
        if not placed[i] and transient_px[i] == 0:
            out[i] = blamed
            continue
        share = _running(share, has_share, 1.0 if transient_px[i] > 0 else 0.0, window)
        has_share = True
        if transient_px[i] > 0 and math.isfinite(at[i]):
            place = _running(place, has_place, at[i], window)
            place_sq = _running(place_sq, has_sq, at[i] * at[i], window)
            has_place = has_sq = True
        if frame[i] >= start_frame:
            frequent = share > share_stale or (blamed != 0 and share > share_clear)
            if not frequent:
                blamed = 0
            else:
                wandering = True
                if has_place and has_sq:
                    wandering = math.sqrt(_max(place_sq - place * place, 0.0)) > fixed_spread
                blamed = 1 if wandering else 2
        out[i] = blamed
    state[0], state[1], state[2] = share, place, place_sq
    state[3], state[4], state[5] = 1.0 if has_share else 0.0, 1.0 if has_place else 0.0, 1.0 if has_sq else 0.0
    state[6] = blamed


def _bound_run(state, blame, table, start, grid_step, placed, information, x, rows_averaged, gain, free_light,
               transient_px, rejected_px, focus, field, chi2_suspect, window, suspect, kept_limit, out):
    """BoundWatch.step over frames: state (has kept, kept, has blame); blame (transients, pixels,
    focus, light); out: -1 none, 0..3 the family blamed in that order, 4 geometry."""
    has_kept, kept_avg, has_blame = state[0] != 0.0, state[1], state[2] != 0.0
    last = table.size - 2
    for i in range(x.size):
        out[i] = -1
        if not (placed[i] and math.isfinite(information[i]) and math.isfinite(x[i])):
            continue
        position = (x[i] - start) / grid_step
        index = int(position)
        if 0 > index:
            index = 0
        if last < index:
            index = last
        fraction = _min(_max(position - index, 0.0), 1.0)
        reference = (table[index] + fraction * (table[index + 1] - table[index])) * rows_averaged[i]
        if reference <= 0:
            continue
        light = gain[i] * gain[i] if free_light[i] else 1.0
        kept = _min(information[i] / (reference * light), 2.0)
        kept_avg = _running(kept_avg, has_kept, kept, window)
        has_kept = True
        if kept_avg > suspect:
            has_blame = False
            continue
        working = (transient_px[i] > 0, rejected_px[i] > 0, focus[i] != 0.0, free_light[i] or field[i])
        for f in range(4):
            blame[f] = _running(blame[f], has_blame, 1.0 if working[f] else 0.0, window)
        has_blame = True
        if kept_avg >= kept_limit or chi2_suspect[i]:
            continue
        best = 0
        for f in range(1, 4):
            if blame[f] > blame[best]:
                best = f
        out[i] = best if blame[best] > 0.1 else 4
    state[0], state[1], state[2] = 1.0 if has_kept else 0.0, kept_avg, 1.0 if has_blame else 0.0


# ---------------------------------------------------------------- the magnification watch
# sc: Σdᵃ·w·m², Σdᵃ, mean (ppm), its σ (ppm), the variance the trim's stretch and the places add (ppm²), flagged
# p: decay a frame, period (mm), the ageing term (−1/MEMORY), MIN_FRAMES, allowance², Z_ON, Z_OFF

def _age(matrix, ageing: float) -> None:
    """``A·matrix·Aᵀ`` in place, A = I + ageing·e₁e₀ᵀ (one frame on, every age term 1/MEMORY further
    back): the row of the age term gains ageing × the level's, then so does its column."""
    for j in range(6):
        matrix[1, j] = matrix[1, j] + ageing * matrix[0, j]
    for i in range(6):
        matrix[i, 1] = matrix[i, 1] + ageing * matrix[i, 0]


def _magnification_add(normal, noise, right, sc, x: float, m: float, sigma: float, p) -> bool:
    """MagnificationWatch._add of one frame's stretch ``m`` ± ``sigma`` (ppm) at ``x``; True when the
    mean is beyond its limit (whether it turns with the phase is numpy's, in Python), else the flag
    is down (and stays as it was while too few frames are in)."""
    d = p[0]
    w = 1.0 / (sigma * sigma)
    theta = 2.0 * math.pi * x / p[1]
    b = (1.0, 0.0, math.cos(theta), math.sin(theta), math.cos(2.0 * theta), math.sin(2.0 * theta))
    _age(normal, p[2])
    _age(noise, p[2])
    dd = d * d
    for i in range(6):
        for j in range(6):
            outer = w * (b[i] * b[j])
            normal[i, j] = d * normal[i, j] + outer
            noise[i, j] = dd * noise[i, j] + outer
    right[1] = right[1] + p[2] * right[0]
    wm = w * m
    for i in range(6):
        right[i] = d * right[i] + wm * b[i]
    sc[0] = d * sc[0] + wm * m
    sc[1] = d * sc[1] + 1.0
    if sc[1] < p[3]:
        return False
    total = normal[0, 0]
    mean = right[0] / total
    scatter = _max((sc[0] - mean * right[0]) / _max(sc[1] - 1.0, 1.0), 1.0)
    sc[2] = mean
    sc[3] = math.sqrt(noise[0, 0] / (total * total) * scatter + p[4] + sc[4])
    significant = abs(mean) >= (p[6] if sc[5] != 0.0 else p[5]) * sc[3]
    if not significant:
        sc[5] = 0.0
    return significant


def _place_add(roots, total, x: float, w: float, p) -> float:
    """PlaceSpread.add (core/place_spread.py): one frame of weight ``w`` (1/ppm²) at ``x`` into its
    place's decayed sum of √w (p: decay a frame, the place's width in mm, the model's share of a
    frame's variance fixed at a place); the variance (ppm²) the places' own stretch leaves in the
    weighted mean of the stretches, share × Σ_place (Σ√w)² / (Σw)²."""
    d = p[0]
    for b in range(roots.size):
        roots[b] = d * roots[b]
    k = int(math.floor(x / p[1])) % roots.size
    roots[k] = roots[k] + math.sqrt(w)
    total[0] = d * total[0] + w
    spread = 0.0
    for b in range(roots.size):
        spread = spread + roots[b] * roots[b]
    return p[2] * spread / (total[0] * total[0])


def _magnification_run(normal, noise, right, sc, x, m, sigma, use, start: int, p, out,
                       place_roots, place_total, place_p) -> int:
    """MagnificationWatch._add of frames ``start:`` where ``use`` (the flag after each into ``out``),
    each mean's σ widened by what the model's own stretch at its places leaves in it
    (:func:`_place_add`), stopping at a frame whose mean is significant (returned: Python judges its turning
    and goes on from the next); the number of frames when none is."""
    for i in range(start, x.size):
        if use[i]:
            sc[4] = _place_add(place_roots, place_total, x[i], 1.0 / (sigma[i] * sigma[i]), place_p)
            if _magnification_add(normal, noise, right, sc, x[i], m[i], sigma[i], p):
                return i
        out[i] = sc[5] != 0.0
    return x.size


# ---------------------------------------------------------------- the scale watch's running mean
# state: count, starting (1/0), Σ residual/σ² mean, Σ 1/σ² mean, the line's variance at the last frame's place
# p: has line, line offset (µm), scale (ppm), centre (mm), covariance ×3, window, gate², the constant terms of
#    the mean's σ² (calibration structure², reference σ², correction noise², each squared in Python), floor,
#    start limit, suspect limit
def _disagreement_run(state, p, x, ref, bound2, structure_um, scatter, valid, far) -> None:
    """Disagreement.add of each frame in order into ``far``; ``bound2`` the frames' (bound in µm)² and
    ``structure_um`` the model's own error at each reading, both made in Python (``**`` is libm's pow);
    ``valid``: the frames add takes (all three finite, the bound positive)."""
    window = p[7]
    for i in range(x.size):
        count = state[0]
        if valid[i]:
            expected = known2 = 0.0
            if p[0] != 0.0:
                d = (ref[i] - p[3]) * 1e-3
                expected, known2 = p[1] + p[2] * d, _max(p[4] + 2.0 * d * p[5] + d * d * p[6], 0.0)
            residual = ((x[i] - structure_um[i] * 1e-3) - ref[i]) * 1e3 - expected
            variance = bound2[i] + p[10]
            beyond = False
            if count != 0.0:  # _gated
                mean = state[2] / state[3] if state[3] > 0 else 0.0
                deviation = residual - mean
                gate2 = p[8] * (variance * scatter[i] + 1.0 / (count * state[3]))
                if not deviation * deviation <= gate2:
                    residual, beyond = mean + (math.sqrt(gate2) if deviation > 0 else -math.sqrt(gate2)), True
            count = _min(count + 1.0, window)
            state[0] = count
            state[1] = 1.0 if state[1] != 0.0 and count < window else 0.0
            state[2] += (residual / variance - state[2]) / count
            state[3] += (1.0 / variance - state[3]) / count
            state[4] = known2
            if beyond:
                far[i] = True
                continue
        if count == 0.0:  # _far
            far[i] = False
            continue
        sigma2 = 1.0 / (count * state[3]) + state[4] + p[9] + p[10] + p[11]
        mean = state[2] / state[3] if state[3] > 0 else 0.0
        limit = p[13] if state[1] != 0.0 else p[14]
        far[i] = abs(mean) > _max(limit * math.sqrt(sigma2), p[12])


if COMPILED:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _disagreement_run = _jit(_disagreement_run)
    _age, _magnification_add, _magnification_run = _jit(_age), _jit(_magnification_add), _jit(_magnification_run)
    _place_add = _jit(_place_add)
    _max, _min, _running, slide_window = _jit(_max), _jit(_min), _jit(_running), _jit(slide_window)
    _chi2_per_dof, _update, _reset = _jit(_chi2_per_dof), _jit(_update), _jit(_reset)
    _reference_run = _jit(_reference_run)
    _grating_run, _light_run, _transient_run, _bound_run = (_jit(_grating_run), _jit(_light_run),
                                                            _jit(_transient_run), _jit(_bound_run))
