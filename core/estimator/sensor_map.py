"""What sits on the sensor's side of the image, learned while tracking: a gain and an offset per sample.

Dust on the camera's window, a veil forming on it, a changed vignetting: each changes the same samples
whatever the stage does. A sample's gray value is then ``(1 + f)·h + e`` of what the calibrated model
predicts (h, through the estimator's state), with f (the share of the light it takes or adds) and e
(light scattered into it, gray) that sample's own. They are slow parameters of the estimator's
measurement model, each sample's pair estimated by its own small Kalman filter from what the frames
leave at that sample:

- **Untouched** samples are as calibrated (f = e = 0, known): the map costs a steady frame nothing.
- **A jump**: a sample whose residual fails its test at the estimator's one false-alarm rate (shared
  over the frame's samples) has had something land on it; its pair's covariance widens by the
  declared jump (``map_jump_gain``, ``map_jump_offset``), and from then on it drifts at the declared
  rates (``map_rate_gain``, ``map_rate_offset``) and is updated by every placed frame.
- **The motion tells f from e**: at rest a sample sees one gray value, which pins only the combination
  ``f·h + e`` at that h; as the print moves under it, h changes and the two separate. Until they have,
  the pair's covariance along the unresolved direction is large and the sample counts for little in
  the position (its weight is the noise model's with the map's variance at the predicted h added):
  the frame's bound is honest while the map is uncertain. A mark on the print moves on with the
  stage: the sample it left fails its test again and jumps back, never resolved into the map.

The frame the estimator updates with is the raw one seen through the map: ``(y − e)/(1 + f)``, its
weight scaled to match (:func:`apply`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from graytrack.core import kernels
from graytrack.core.estimator.marks import CHANGED_Z, MarkShape, ToldMarks, figure, runs  # noqa: F401 (CHANGED_Z: told here)

# a sample whose light the map says is nearly all taken (1 + f below this) carries nothing of the position
BLOCKED = 0.05
TRAVEL_PX = 1.0  # pixels of the print's motion a candidate must hold its own over before either map uses it: seen
# by two pixels, a mark on the print has moved on and one on the sensor's side has stayed (print_map.py's too)


def apply(y: np.ndarray, mask: np.ndarray, touched: np.ndarray, f: np.ndarray, e: np.ndarray, sff: np.ndarray,
          sfe: np.ndarray, see: np.ndarray, h: np.ndarray, noise: np.ndarray, y_out: np.ndarray,
          mask_out: np.ndarray) -> None:
    """The frame seen through the map into ``y_out`` and ``mask_out``: on a touched sample ``(y − e)/(1 + f)``,
    its weight that of the raw sample's noise (at the last predicted ``h``) with the map's variance added,
    scaled by (1 + f)²; elsewhere the frame as it is. ``noise``: read variance, shot gain, dark level."""
    read_var, shot_gain, dark = noise[0], noise[1], noise[2]
    for p in range(y.size):
        y_out[p] = y[p]
        mask_out[p] = mask[p]
        if not touched[p] or mask[p] <= 0.0:
            continue
        scale = 1.0 + f[p]
        if scale < BLOCKED:
            mask_out[p] = 0.0
            continue
        y_out[p] = (y[p] - e[p]) / scale
        hp = h[p]
        model_signal = hp - dark
        raw_signal = scale * hp + e[p] - dark
        var_model = read_var + shot_gain * (model_signal if model_signal > 0.0 else 0.0)
        var_raw = read_var + shot_gain * (raw_signal if raw_signal > 0.0 else 0.0)
        if mask[p] * (hp * hp * sff[p] + see[p]) > var_raw:
            # not yet resolved: the gain and the offset each still less known than the sample's noise (the motion
            # has not yet separated them). What was learned of their combination holds the position the frames
            # had when it was learned; used for the position, the map would carry that position on, a drift fed
            # by its own memory. The sample waits outside the position until the motion has resolved it.
            mask_out[p] = 0.0
            continue
        var_map = hp * hp * sff[p] + 2.0 * hp * sfe[p] + see[p]
        if var_map < 0.0:
            var_map = 0.0
        mask_out[p] = mask[p] * var_model * scale * scale / (var_raw + mask[p] * var_map)


def learn(y: np.ndarray, expected: np.ndarray, rival: np.ndarray, rival_var: np.ndarray, noise_var: np.ndarray,
          mask: np.ndarray, level: float, dt: float, z2: float, params: np.ndarray, touched: np.ndarray, f: np.ndarray,
          e: np.ndarray, sff: np.ndarray, sfe: np.ndarray, see: np.ndarray, evidence: np.ndarray, rivalry: np.ndarray,
          teach: bool, h: np.ndarray, jumped_out: np.ndarray, moved: float, travel: np.ndarray) -> int:
    """One placed frame into the map's touched samples. ``y``: the frame's raw values, ``expected``: what the
    posterior state predicts at each sample before the sensor's side (the model's value, with what the print's
    map holds there), ``rival``, ``rival_var``: what the print's side says the sample is where the sensor's side
    is as calibrated, and that account's variance (``expected`` and 0, but where the print's map holds a
    candidate there the motion has not decided, that candidate's prediction and variance), ``noise_var``:
    the noise model's variance there (kernel.residuals), ``mask``: the raw frame's weights, ``level``: the
    calibration's χ² per sample, ``dt``: the interval since the last frame (s), ``z2``: the per-sample test's
    threshold (σ²), ``params``: the jumps' and the rates' variances (gain jump, offset jump; gain rate, offset
    rate per second). Each touched sample's pair is moved on by its rates and updated by its residual; one
    whose residual fails its test jumps first (a change beyond what the pair holds). ``evidence``: each
    touched sample's log-likelihood ratio of "changed" (its pair) over "as calibrated" (f = e = 0) over the
    frames since its last jump (each one's predictive density); where it falls below nought the frames speak
    for the calibration again (a glint gone, a print mark moved on, a shadow passed) and the sample is as
    calibrated again. ``rivalry``: the same ratio over the print's side's account (``rival``): at the pixel a
    mark landed at, the two candidates tell the same and it stays near nought until the motion carries the
    print's candidate away — what tells the maps apart (:meth:`SensorMap.learned`), where ``evidence`` says only
    that something changed. Told apart the other way, the sample is let go too: where the print's side's account
    beats the pair by one sample's test at the false-alarm rate (its log at −z²/2, the bar a mark is learned at),
    the change is the print's (dust settling, a smudge the print carries past the pixel) and its candidate
    there holds it; kept, the pair would hold the sample aside frame after frame as the mark moves on.
    ``teach``: whether the pairs learn from this frame (not where the frame's position is carried by the state's
    memory: what it leaves at a sample then speaks of the position as much as of the
    sample); the evidence is weighed and a sample let go either way, so none is held aside by a map that
    cannot learn. ``h`` out: each sample's predicted model value; ``jumped_out`` out: the samples that jumped.
    ``moved``: how far the print moved under the pixels since the last frame (px); ``travel``: over how much of the
    print's motion each sample's rivalry has stayed above nought (a mark on the sensor's side keeps beating the
    print's side while the print moves under it; a speck the print carries onto the pixel beats it for a frame or
    two, and is gone). Returns how many jumped."""
    jump_ff, jump_ee, rate_ff, rate_ee = params[0], params[1], params[2] * dt, params[3] * dt
    jumped = 0
    for p in range(y.size):
        hp = expected[p]
        h[p] = hp
        jumped_out[p] = False
        if mask[p] <= 0.0:
            continue
        r = y[p] - ((1.0 + f[p]) * hp + e[p])  # the raw sample's residual against what the pair predicts
        var_y = noise_var[p] * level / mask[p]
        if not touched[p]:
            continue
        sff[p] += rate_ff
        see[p] += rate_ee
        s = hp * hp * sff[p] + 2.0 * hp * sfe[p] + see[p] + var_y
        if r * r > z2 * s:
            # a change beyond what the pair holds: the evidence for a change starts again with this frame's
            evidence[p] = 0.0
            rivalry[p] = 0.0
            travel[p] = 0.0
            sff[p] += jump_ff
            see[p] += jump_ee
            s = hp * hp * sff[p] + 2.0 * hp * sfe[p] + see[p] + var_y
            jumped += 1
            jumped_out[p] = True
        # the frame's evidence for the pair over the calibration and over the print's side's account at this
        # sample (each one's predictive density)
        r0 = y[p] - hp
        evidence[p] += 0.5 * (r0 * r0 / var_y - r * r / s - math.log(s / var_y))
        r0 = y[p] - rival[p]
        s0 = var_y + rival_var[p]
        rivalry[p] += 0.5 * (r0 * r0 / s0 - r * r / s - math.log(s / s0))
        travel[p] = travel[p] + moved if rivalry[p] > 0.0 else 0.0
        if evidence[p] < 0.0 or rivalry[p] < -0.5 * z2:  # (the calibration's account or the print's is better)
            touched[p] = False
            f[p], e[p], sff[p], sfe[p], see[p], evidence[p], rivalry[p] = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            travel[p] = 0.0
            continue
        if not teach:
            continue
        kf = (hp * sff[p] + sfe[p]) / s
        ke = (hp * sfe[p] + see[p]) / s
        f[p] += kf * r
        e[p] += ke * r
        sff[p] -= kf * kf * s
        sfe[p] -= kf * ke * s
        see[p] -= ke * ke * s
    return jumped


def land(residual: np.ndarray, weight: np.ndarray, level: float, z2: float, most: float, hold: float,
         jump_ff: float, jump_ee: float, reach: int, row: int, touched: np.ndarray, sff: np.ndarray, see: np.ndarray,
         evidence: np.ndarray, rivalry: np.ndarray, core: np.ndarray) -> int:
    """Samples something has landed on, from a frame's solve: ``residual`` and ``weight`` (the noise model's
    inverse variance with the frame's mask) as the update left them. An untouched sample whose residual
    fails its test (``z2``, σ², against the noise model at the calibration's ``level``) is touched, its pair
    widened by the jumps, and so are the samples within ``reach`` of it along its row (a mark on the window
    is out of focus: its soft edge, below the test, lands with it) — as long as no more than ``most`` of the
    samples the frame still uses fail at once (where more do, the state is misplaced: its light, its position,
    the state's to answer, not the map's; what the map already holds aside says nothing of that) and the map
    then holds no more than ``hold`` of the frame's samples (a full map takes nothing more, and what fails is
    the robust weights'). Returns the samples that failed (as a negative count where they were too many:
    nothing landed); ``core`` out: those samples (the print's map's candidates too, print_map.py)."""
    fresh, held, usable = 0, 0, 0
    for p in range(residual.size):
        core[p] = False
        if weight[p] <= 0.0:
            if touched[p]:
                held += 1
            continue
        usable += 1
        if not touched[p] and residual[p] * residual[p] * weight[p] / level > z2:
            core[p] = True
            fresh += 1
    if fresh == 0:
        return 0
    if fresh > most * usable:
        return -fresh
    if held + fresh > hold * (held + usable):
        for p in range(residual.size):
            core[p] = False
        return 0  # (the map is full: what fails is the outlier model's to weigh, the state not suspect)
    for p in range(residual.size):
        if not core[p]:
            continue
        start, stop = p - reach, p + reach + 1
        first = (p // row) * row
        if start < first:
            start = first
        if stop > first + row:
            stop = first + row
        for q in range(start, stop):
            if weight[q] > 0.0 and not touched[q]:
                touched[q] = True
                evidence[q] = 0.0
                rivalry[q] = 0.0
                sff[q] = jump_ff
                see[q] = jump_ee
    return fresh


if kernels.COMPILED:
    _jit = kernels.numba.njit(cache=True, nogil=True, error_model="numpy")
    apply = _jit(apply)
    learn = _jit(learn)
    land = _jit(land)


class SensorMap(ToldMarks):
    """The map of ``n`` samples: each one's gain and offset against calibration with their covariance,
    and whether anything has landed on it. ``noise``: the noise model (read variance, shot gain, dark);
    ``level``: the calibration's χ² per sample; ``z``: the per-sample test in σ; ``params``: as
    :func:`learn` takes them."""

    # a mark: a run of neighbouring learned samples along a row (marks.py tells them as they change)
    SHAPE = MarkShape("first_px", "last_px", ("row", "first_px", "last_px", "samples"),
                      (("gain", "gain_sigma"), ("offset_gray", "offset_sigma_gray")))

    def __init__(self, n: int, noise: np.ndarray, level: float, z: float, params: np.ndarray,
                 mean_gray: float, most: float, reach: int, row: int, hold: float = 1.0) -> None:
        self.noise, self.level, self.z2, self.params = noise, float(level), float(z) ** 2, params
        self.reach, self.row = int(reach), int(row)
        self.stride = self.row  # samples a row
        self.most, self.hold = float(most), float(hold)
        self.mean_gray = float(mean_gray)
        self.touched = np.zeros(n, dtype=np.bool_)
        self.f, self.e = np.zeros(n), np.zeros(n)
        self.sff, self.sfe, self.see = np.zeros(n), np.zeros(n), np.zeros(n)
        self.evidence = np.zeros(n)
        self.rivalry = np.zeros(n)  # the evidence over the print's side's account (learn)
        self.travel = np.zeros(n)  # the print's motion (px) under the sample while its rivalry held (learn)
        # each sample's last predicted model value, by which a touched sample's noise is weighed (apply): until a
        # frame the map learns from says, the light's mean
        self.h = np.full(n, self.mean_gray)
        self.active = False  # anything landed yet: else the map is the identity and costs nothing
        self.jumps = 0
        self._y, self._mask, self._noise_var = np.empty(n), np.empty(n), np.empty(n)
        self.core = np.zeros(n, dtype=np.bool_)  # the samples the last land found failing, held by neither map
        self.jumped = np.zeros(n, dtype=np.bool_)  # the held samples the last learn found failing their pair

    def reset(self) -> None:
        self.touched[:] = False
        for array in (self.f, self.e, self.sff, self.sfe, self.see, self.evidence, self.rivalry, self.travel):
            array[:] = 0.0
        # (a frame may land samples before the map has learned from any since: they are weighed at the light's mean,
        # not at what a frame before the reset left)
        self.h[:] = self.mean_gray
        self.active = False
        self.jumps = 0

    def seen(self, y: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The frame as the estimator updates with it (its own arrays; the frame's where nothing landed)."""
        if not self.active:
            return y, mask
        apply(y, mask, self.touched, self.f, self.e, self.sff, self.sfe, self.see, self.h, self.noise, self._y,
              self._mask)
        return self._y, self._mask

    def land(self, residual: np.ndarray, weight: np.ndarray, hold: float | None = None) -> int:
        """Samples something landed on, from a frame's solve (:func:`land`); the frame is to be seen again.
        A negative count: that many failed, too many for the map (nothing landed). ``hold``: the share of the
        frame the map may hold (its own where None)."""
        fresh = land(residual, weight, self.level, self.z2, self.most, self.hold if hold is None else hold,
                     self.params[0], self.params[1],
                     self.reach,
                     self.row, self.touched, self.sff, self.see, self.evidence, self.rivalry, self.core)
        if fresh > 0:
            self.active = True
            self.jumps += fresh
        return fresh

    def learn(self, y: np.ndarray, expected: np.ndarray, rival: np.ndarray, rival_var: np.ndarray,
              noise_var: np.ndarray, mask: np.ndarray, dt: float, teach: bool = True, moved: float = 0.0) -> int:
        jumped = learn(y, expected, rival, rival_var, noise_var, mask, self.level, dt, self.z2, self.params,
                       self.touched, self.f, self.e, self.sff, self.sfe, self.see, self.evidence, self.rivalry, teach,
                       self.h, self.jumped, moved, self.travel)
        self.jumps += jumped
        if not self.touched.any():
            self.active = False  # (every candidate let go: the map is the identity again, and costs nothing)
        return jumped

    def learned(self, resolved: float = 0.05) -> np.ndarray:
        """The samples the map holds a change for, told apart from the print by the motion: the pair known
        to ``resolved`` of the light in both directions (the motion has separated f from e), beyond zero at
        the false-alarm rate's per-sample threshold, and its evidence over the calibration (which holds what
        the print's map uses there) and over the print's side's account (its candidate there, while it had one)
        each that of one sample's test at that rate (the likelihood ratio's log at z²/2, as a node of the
        print's map needs against the sensor's side): a pair the frames barely tell from the calibration is not
        a mark, nor one within what the calibration itself leaves at the sample, nor one the print's candidate
        explained as well while it lay under the sample (a speck on the print seen while the stage rested), nor one
        that has beaten it over less than ``TRAVEL_PX`` of the print's motion (a speck the print carries onto the
        pixel, where the print's side holds no candidate: the pair's own width takes it for a frame or two)."""
        out = np.zeros(self.touched.size, dtype=bool)
        where = np.flatnonzero(self.touched)
        if where.size == 0:
            return out
        g = max(self.mean_gray, 1.0)
        # what the calibration itself leaves at a sample beyond the noise (its χ² per sample above one) is an
        # offset no frame tells from a change: a mark is beyond it as well as beyond the pair's own uncertainty
        read_var, shot_gain, dark = self.noise[0], self.noise[1], self.noise[2]
        misfit = max(self.level - 1.0, 0.0) * (read_var + shot_gain * np.maximum(self.h[where] - dark, 0.0))
        a, b, d = self.sff[where], self.sfe[where] / g, self.see[where] / (g * g)
        largest = 0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b * b)
        d = d + misfit / (g * g)
        det = np.maximum(a * d - b * b, 1e-300)
        x, w = self.f[where], self.e[where] / g
        distance = (d * x * x - 2.0 * b * x * w + a * w * w) / det
        out[where] = (largest < resolved ** 2) & (distance > self.z2) & (self.evidence[where] >= 0.5 * self.z2) & \
            (self.rivalry[where] >= 0.5 * self.z2) & (self.travel[where] >= TRAVEL_PX)
        return out

    def describe(self) -> dict[str, object]:
        learned = np.flatnonzero(self.learned())
        return {"touched_samples": int(self.touched.sum()), "learned_samples": int(learned.size),
                "jumps": self.jumps, "samples": learned.tolist(), "gain": (1.0 + self.f[learned]).round(4).tolist(),
                "offset_gray": self.e[learned].round(3).tolist()}

    # ------------------------------------------------------------------ kept between runs, told as it changes
    # (what the daemon keeps with its model of record, service/daemon/map_store.py, and says in its event log)

    def state(self) -> dict[str, Any]:
        """The map as a JSON document (:meth:`restore` reads it back): the touched samples' pairs with their
        covariance and evidence, which of them are learned, and the marks those make. Untouched samples are as
        calibrated and are not written."""
        where = np.flatnonzero(self.touched)
        learned = self.learned()
        return {"version": MAP_STATE_VERSION, "samples": int(self.touched.size), "pixels": self.row,
                "rows": self.touched.size // self.row, "jumps": int(self.jumps), "touched": where.tolist(),
                **{name: getattr(self, name)[where].tolist() for name in PAIR},
                "learned": learned[where].tolist(), "marks": self.marks(learned)}

    def restore(self, state: dict[str, Any]) -> None:
        """The map as ``state`` (:meth:`state`) holds it; ValueError (one line) when it is not one this map can
        hold: another sample count, a bad shape, a value that is not finite or a covariance that is not one.
        Nothing changes then. The restored marks are what the next look compares against (not learned again)."""
        try:
            if state.get("version") != MAP_STATE_VERSION:
                raise ValueError(f"version {state.get('version')!r}, not {MAP_STATE_VERSION}")
            if (int(state["samples"]), int(state["pixels"])) != (self.touched.size, self.row):
                raise ValueError(f"{state['samples']} samples of {state['pixels']} pixels, the map has "
                                 f"{self.touched.size} of {self.row}")
            where = np.asarray(state["touched"], dtype=np.int64).reshape(-1)
            # (a document written before the rivalry was kept: the evidence over the calibration stands for it; before
            # the travel was: its samples as carried far enough)
            pairs = {name: np.asarray(state[name if name in state or name != "rivalry" else "evidence"],
                                      dtype=np.float64) if name != "travel" or name in state else
                     np.full(len(state["touched"]), TRAVEL_PX) for name in PAIR}
            jumps = int(state.get("jumps", 0))
        except (KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"not a sensor map state ({type(exc).__name__}: {exc})") from None
        if any(values.shape != where.shape for values in pairs.values()):
            raise ValueError(f"{where.size} touched samples but the pairs' arrays have lengths "
                             f"{sorted({values.size for values in pairs.values()})}")
        if where.size and (where.min() < 0 or where.max() >= self.touched.size or np.unique(where).size != where.size):
            raise ValueError(f"touched samples must be distinct and within 0..{self.touched.size - 1}")
        if not all(np.all(np.isfinite(values)) for values in pairs.values()):
            raise ValueError("a gain, offset, covariance or evidence that is not finite")
        sff, sfe, see = pairs["sff"], pairs["sfe"], pairs["see"]
        if np.any(sff < 0) or np.any(see < 0) or np.any(sfe * sfe > sff * see * (1.0 + COVARIANCE_SLACK) + 1e-300):
            raise ValueError("a gain/offset covariance that is not positive semidefinite")
        self.reset()
        self.touched[where] = True
        for name, values in pairs.items():
            getattr(self, name)[where] = values
        # the model's value at each touched sample is the next frame's to say (learn): until then the light's mean
        self.h[where] = self.mean_gray
        # What the last run had not decided starts again as a candidate just landed (as calibrated, the jumps'
        # variance, no evidence): its pair and evidence spoke of the print as it passed then, and the rig may have
        # changed while it was off. Kept, a candidate would meet this run's first deviation at its sample with the
        # last run's frames behind it (its pair resolved, its evidence won) and be told before the motion has said
        # whose it is; landed again, it waits outside the position until this run's motion decides.
        undecided = where[~self.learned()[where]]
        for name in PAIR:
            getattr(self, name)[undecided] = 0.0
        self.sff[undecided], self.see[undecided] = self.params[0], self.params[1]
        self.active = bool(where.size)
        self.jumps = max(jumps, 0)
        self.restore_told()

    def marks(self, learned: np.ndarray | None = None) -> list[dict[str, Any]]:
        """The learned samples (:meth:`learned`) as marks: each run of neighbouring learned samples along a row,
        with its mean gain ``1 + f`` and offset ``e`` (gray) and their σ (a sample's, the RMS over the mark's)."""
        learned = self.learned() if learned is None else learned
        marks = []
        for start, stop in runs(learned, self.row):
            span = slice(start, stop)
            marks.append({"row": start // self.row, "first_px": start % self.row, "last_px": (stop - 1) % self.row,
                          "samples": stop - start, "gain": figure(1.0 + float(self.f[span].mean())),
                          "gain_sigma": figure(math.sqrt(float(self.sff[span].mean()))),
                          "offset_gray": figure(float(self.e[span].mean())),
                          "offset_sigma_gray": figure(math.sqrt(float(self.see[span].mean())))})
        return marks


MAP_STATE_VERSION = 1  # of :meth:`SensorMap.state`'s document
# a touched sample's arrays, as the state document names them
PAIR = ("f", "e", "sff", "sfe", "see", "evidence", "rivalry", "travel")
COVARIANCE_SLACK = 1e-6  # relative: a pair's covariance rounded through JSON may sit this far past semidefinite


__all__ = ["SensorMap", "apply", "learn"]
