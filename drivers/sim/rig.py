"""The virtual rig: target + light + optics + sensor + stage + grating + timing, rendered to frames.

Rendering. The light reaching pixel (r, u) when the stage is at x is::

    L = flicker(t) · V(r, u) · G_target(x + s[r,u], y[r,u]) · Re Σ_i C_i(r,u) e^{ji θ(x + s[r,u])}

(V: vignetting, G_target: the illumination field and defects fixed to the target, C: the target's
Fourier coefficients, already blurred by defocus). When the target phase is affine in x (no chirp),
``θ(x + s) = κx + κs`` and the sum splits into a per-frame basis ``e^{jiκx}`` times a per-pixel matrix
``C_i e^{jiκs}``: a frame costs one small matrix product, whatever the number of rows. Motion blur
is exact in that form too — the mean of ``e^{jiκx(t)}`` over a linear piece of motion is
``e^{jiκx_mid}·sinc(iκΔx/2π)``. Target-fixed gains and chirp take a slower path that evaluates each
pixel at sub-samples of the exposure.

What sits on the camera's side and changes during a run (dust landing on its window, a veil, a
changed vignetting: camera_side.py) then darkens the light on the pixels it covers, whatever the
stage does. The light then goes through the sensor (sensor.py). Ground truth — true exposure instants and
positions, fixed patterns, the true period — is returned as a :class:`Truth`, never put into the
recording.
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from graytrack.core.recording import CAMERA_TRIGGER, SENSOR_RANGE, STAGE_ACCELERATION, STAGE_PHASES, Recording
from graytrack.drivers.sim import illumination as illum
from graytrack.drivers.sim import target as tgt
from graytrack.drivers.sim.camera_side import CameraSide, CameraSideConfig
from graytrack.drivers.sim.glints import GlintConfig, Glints
from graytrack.drivers.sim.grating import GratingConfig, GratingReadout
from graytrack.drivers.sim.illumination import IlluminationConfig
from graytrack.drivers.sim.optics import (OpticsConfig, defocus_attenuation, drifted_offsets, focus_attenuation,
                                         off_target, pixel_geometry)
from graytrack.drivers.sim.sensor import FULL_SCALE_GRAY, Sensor, SensorConfig
from graytrack.drivers.sim.stage import SimStage, SimStageConfig, Trajectory, Vibrating, oscillation, sweep
from graytrack.drivers.sim.target import TargetConfig
from graytrack.drivers.sim.timing import TimingConfig, frame_clock

ProgressCallback = Callable[[float, str], None]

# Elements (frames × rows × pixels) rendered per chunk: bounds memory, keeps arrays in cache.
CHUNK_ELEMENTS = 1 << 18


def rng_for(seed: int, *names: str) -> np.random.Generator:
    """An independent random stream per (seed, component): switching one effect on does not
    reshuffle the noise or fixed patterns of the others."""
    keys = [int(seed) & 0xFFFFFFFF] + [zlib.crc32(name.encode()) for name in names]
    return np.random.default_rng(keys)


@dataclass
class RigConfig:
    """Everything that defines a virtual rig. Scenarios build one; effects edit it."""

    scenario: str = "custom"
    target: TargetConfig = field(default_factory=TargetConfig)
    illumination: IlluminationConfig = field(default_factory=IlluminationConfig)
    optics: OpticsConfig = field(default_factory=OpticsConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    stage: SimStageConfig = field(default_factory=SimStageConfig)
    grating: GratingConfig = field(default_factory=GratingConfig)
    timing: TimingConfig = field(default_factory=TimingConfig)
    glints: GlintConfig = field(default_factory=GlintConfig)
    camera_side: CameraSideConfig = field(default_factory=CameraSideConfig)  # fixed to the pixels, changing in a run
    stroke_mm: tuple[float, float] = (0.0, 10.46)
    default_seconds: float = 10.0
    motion: str = "sweep"  # default trajectory: "sweep" once over the stroke, or "oscillation"
    motion_hz: float = 2.0  # oscillation frequency (full stroke amplitude)
    effects: list[str] = field(default_factory=list)  # canonical specs of the effects applied
    n_orders: int = 8  # Fourier orders kept when print gamma creates harmonics


@dataclass
class Truth:
    """Ground truth of a recording, frame by frame for the frames kept (aligned with the file).

    Arrays per frame ``(K,)``: ``t_s`` true exposure mid-instant, ``x_mm`` true position then,
    ``v_mm_s`` velocity, ``x_mean_mm`` position averaged over the exposure, ``reference_error_mm``
    (reference − x_mm), ``light_gain`` (flicker), ``frame_index`` (index before drops). Per pixel
    ``(R, n)``: ``pixel_x_mm`` target offset seen, ``pixel_gain`` (PRNU × vignetting),
    ``pixel_offset_gray`` (DSNU). Scalars: ``period_mm`` (true printed period), ``noise_gray``.
    ``info``: the scenario, effects, seed and whole configuration (the print's defects with the instant
    each appears); with changes on the camera's side, also the window's specks with the instant each
    landed and the pixels each marks, and the veil's pixels (:meth:`CameraSide.truth`).
    """

    t_s: np.ndarray
    x_mm: np.ndarray
    v_mm_s: np.ndarray
    x_mean_mm: np.ndarray
    reference_error_mm: np.ndarray
    light_gain: np.ndarray
    frame_index: np.ndarray
    pixel_x_mm: np.ndarray
    pixel_gain: np.ndarray
    pixel_offset_gray: np.ndarray
    period_mm: float
    noise_gray: float
    info: dict[str, Any] = field(default_factory=dict)

    def save(self, path: str | Path) -> Path:
        """Write as ``.npz`` (arrays by name, ``info`` as a JSON string)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {k: v for k, v in vars(self).items() if k != "info"}
        arrays["info"] = np.array(json.dumps(self.info, sort_keys=True))
        with open(path, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "Truth":
        with np.load(path, allow_pickle=False) as data:
            values = {k: data[k] for k in data.files}
        info = json.loads(str(values.pop("info")))
        for key in ("period_mm", "noise_gray"):
            values[key] = float(values[key])
        return cls(**values, info=info)


class VirtualRig:
    """A simulated camera + target + stage + grating, deterministic under ``seed``.

    Fixed patterns (PRNU, DSNU, defect positions) come from ``seed`` alone. Noise comes from a
    stream that advances with every ``render``/``record`` call: a fresh rig with the same seed
    repeats the same recordings in the same order, unless ``run`` names another session.
    """

    def __init__(self, config: RigConfig, seed: int = 0, run: int = 0):
        self.config = config
        self.seed = int(seed)
        # ``run`` > 0: another session of the same rig (same fixed patterns, fresh noise), as when a
        # calibrated camera records the run it measures.
        self._noise_rng = rng_for(seed, "noise") if run == 0 else rng_for(seed, "noise", f"run {run}")
        self._timing_rng = rng_for(seed, "timing")
        opt, tcfg = config.optics, config.target
        self.geometry = pixel_geometry(opt)
        self.sensor = Sensor(
            config.sensor, self.geometry.full_r, self.geometry.full_u, (opt.full_height, opt.full_width),
            rng_for(seed, "sensor-pattern"),
        )
        coeffs = tgt.fourier_coefficients(tcfg, self.geometry.u, config.n_orders)
        orders = np.arange(coeffs.shape[0])
        self._orders = orders
        coeffs = coeffs * defocus_attenuation(opt, orders, tcfg.true_period_mm)[:, None, None]
        beyond = off_target(opt)
        if beyond.any():  # pixels past the print's edge: a plain surface, no period
            coeffs[:, beyond] = 0.0
            coeffs[0, beyond] = opt.background_gray
        self._vignetting = illum.camera_field_gain(config.illumination, self.geometry.radius2)
        self._coeffs = coeffs * self._vignetting  # (M+1, R, n), phase reference: target x
        self._kappa = 2 * math.pi / tcfg.true_period_mm
        # fast path: fold the pixel offsets into the coefficients → real matrix (2M+1, R·n)
        folded = self._coeffs * np.exp(1j * orders[:, None, None] * self._kappa * self.geometry.x_mm)
        flat = folded.reshape(orders.size, -1)
        self._matrix = np.concatenate([flat.real, -flat[1:].imag]).astype(np.float64)
        # a smooth (quadratic) light field fixed to the target stays on the fast path:
        # G(x + s) = G(x) + G'(x)·s + ½G''·s², one extra matrix per power of s
        self._matrix_s = [self._matrix * self.geometry.x_mm.reshape(1, -1) ** p for p in (1, 2)]
        self._slow = (not tcfg.affine) or bool(tcfg.defects) or bool(tcfg.growths) or opt.moves
        self._row_y = self.geometry.y_mm.mean(axis=1)
        self._glare = illum.glare(config.illumination, opt.n_rows, opt.n_pixels)
        self._duplicate_rng = rng_for(seed, "duplicates") if run == 0 else rng_for(seed, "duplicates", f"run {run}")
        gcfg = config.glints
        self._glints = Glints(gcfg, rng_for(gcfg.seed, "glints", f"run {run}"), config.timing.frame_rate_hz,
                              opt.n_rows) if gcfg.probability > 0 else None
        side = config.camera_side
        self.camera_side = CameraSide(side, opt.n_rows, opt.n_pixels, self.geometry.radius2) if side.active else None

    # ----- shape and nominal figures --------------------------------------------------------
    @property
    def n_pixels(self) -> int:
        return self.config.optics.n_pixels

    @property
    def n_rows(self) -> int:
        return self.config.optics.n_rows

    @property
    def pixel_pitch_mm(self) -> float:
        """Nominal α·d (what a user would measure or be told)."""
        return self.config.optics.pixel_pitch_mm

    @property
    def period_mm(self) -> float:
        """Nominal printed period τ_w (the true one is in :class:`Truth`)."""
        return self.config.target.period_mm

    @property
    def exposure_s(self) -> float:
        return self.config.timing.exposure_s

    @property
    def frame_rate_hz(self) -> float:
        return self.config.timing.frame_rate_hz

    @property
    def frame_dtype(self) -> np.dtype:
        return self.sensor.output_dtype

    # ----- parts a driver can use -----------------------------------------------------------
    def make_stage(self, position_mm: float | None = None, t_s: float = 0.0) -> SimStage:
        """A fresh :class:`SimStage` with this rig's stage settings, at the stroke start by default."""
        cfg = SimStageConfig(**vars(self.config.stage))
        return SimStage(cfg, self.config.stroke_mm[0] if position_mm is None else position_mm, t_s)

    def make_grating(self, stage: Trajectory) -> GratingReadout:
        """The rig's grating readout attached to ``stage``."""
        return GratingReadout(stage, GratingConfig(**vars(self.config.grating)))

    def default_trajectory(self, seconds: float | None = None) -> Trajectory:
        """The scenario's motion: by default the calibration-like sweep, once over the stroke at
        constant velocity filling ``seconds``; fast scenarios oscillate over the stroke instead."""
        seconds = self.config.default_seconds if seconds is None else seconds
        start, end = self.config.stroke_mm
        if self.config.motion == "oscillation":
            return oscillation(0.5 * (start + end), 0.5 * (end - start), self.config.motion_hz)
        return sweep(start, end, seconds, self.config.stage)

    # ----- rendering ------------------------------------------------------------------------
    def render(self, x_mm_samples: np.ndarray, t_s: np.ndarray, noise: bool = True,
               exposure_s: float | None = None) -> np.ndarray:
        """Frames ``(K, R, n)`` in the sensor's dtype for the stage motion during each exposure.

        ``x_mm_samples`` is ``(K,)`` (stage still during the exposure) or ``(K, S)``: true positions
        at S instants evenly spaced from the start to the end of each exposure (S ≥ 2); the motion
        is taken as piecewise linear between them, which is exact for constant velocity with S = 2.
        ``t_s`` ``(K,)`` are the exposure mid-instants (they set the flicker phase).
        ``noise=False`` gives the noise-free frames (still quantised). ``exposure_s`` (default: the
        rig's) is the exposure the flicker is averaged over; a camera driver with its own exposure
        setting passes it, and spaces ``x_mm_samples`` over the same window.
        """
        light = self.render_light(x_mm_samples, t_s, exposure_s)
        return self.sensor.expose(light, self._noise_rng if noise else None, t_s)

    def render_light(self, x_mm_samples: np.ndarray, t_s: np.ndarray, exposure_s: float | None = None) -> np.ndarray:
        """Noise-free light reaching each pixel ``(K, R, n)``, float64, before the sensor."""
        x = np.asarray(x_mm_samples, dtype=np.float64)
        x = x[:, None] if x.ndim == 1 else x
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        if x.ndim != 2 or t.shape[0] != x.shape[0]:
            raise ValueError(f"x_mm_samples must be (K,) or (K, S) and t_s (K,), got {x.shape} and {t.shape}")
        R, n = self.n_rows, self.n_pixels
        exposure = self.exposure_s if exposure_s is None else float(exposure_s)
        out = np.empty((x.shape[0], R, n))
        step = max(1, CHUNK_ELEMENTS // (R * n))
        for k0 in range(0, x.shape[0], step):
            k1 = min(k0 + step, x.shape[0])
            focus = focus_attenuation(self.config.optics, self._orders[1:], self.config.target.true_period_mm, t[k0:k1])
            for rows, xs in self._row_exposures(x[k0:k1], exposure):
                light = self._light_slow(xs, t[k0:k1], focus) if self._slow else self._light_fast(xs, focus)
                out[k0:k1, rows] = light.reshape(k1 - k0, R, n)[:, rows]
        if self.config.illumination.shadow.active:  # a cable's shadow on the print: the lamp's light there only
            out *= self.config.illumination.shadow.gain(t, self.geometry.x_mm)
        if self.config.illumination.glare_gray:
            out += self._glare  # the lamp's stray light: it dims and flickers with the lamp
        if self._glints is not None:  # the lamp mirrored by the print: it dims and flickers with it too
            self._glints.add_light(out, t, x.mean(axis=1), self.geometry.x_mm, self.pixel_pitch_mm)
        if self.camera_side is not None:  # window dust, a veil, a changed vignetting: fixed to the pixels
            self.camera_side.apply(out, t, x, exposure)
        gain, ambient = illum.level_change(self.config.illumination, t)
        out *= (illum.flicker_gain(self.config.illumination, t, exposure) * gain)[:, None, None]
        out += ambient[:, None, None]
        return out

    def _row_exposures(self, xs: np.ndarray, exposure_s: float):
        """(rows, positions ``(K, S)`` during their exposure) for each group of rows exposed together:
        all rows at once, or under a rolling shutter each row ``line_time_s`` after the one above
        (centred on the frame's mid-exposure), its positions those of the frame's motion moved on by
        the frame's velocity × its delay (the samples span the exposure: exact at constant velocity)."""
        line = self.config.timing.line_time_s
        if not line or self.n_rows == 1 or xs.shape[1] < 2 or not exposure_s > 0:
            yield slice(None), xs
            return
        velocity = (xs[:, -1] - xs[:, 0]) / exposure_s
        for r in range(self.n_rows):
            yield slice(r, r + 1), xs + (velocity * (r - 0.5 * (self.n_rows - 1)) * line)[:, None]

    def _basis(self, theta: np.ndarray) -> np.ndarray:
        """Real basis ``[1, cos iθ, sin iθ]`` ``(K, 2M+1)`` for fundamental phases θ ``(K,)``."""
        i = self._orders[1:]
        arg = theta[:, None] * i[None, :]
        return np.concatenate([np.ones((theta.size, 1)), np.cos(arg), np.sin(arg)], axis=1)

    def _light_fast(self, xs: np.ndarray, focus: np.ndarray | None = None) -> np.ndarray:
        """Affine phase, no defects: exposure-averaged basis × per-pixel matrices.

        ``focus`` ``(K, M)``: each frame's gain of each order from a focus drift (a blur acts on the
        target's orders exactly as the motion's sinc does, so it folds into the same damping).

        Each linear piece of the motion (mid-point x_m, half-length h) averages ``e^{jωx}`` to
        ``e^{jωx_m}·sinc(ωh/π)`` exactly. A smooth light field fixed to the target,
        ``G(x + s) = G(x_m) + G'(x_m)(s + δ) + ½G''(s + δ)²`` over the piece, adds the powers of the
        pixel offset s (extra matrices) and the first moment ``⟨δ e^{jωδ}⟩`` (the light changes while
        the print slides by), which is what makes a blurred frame under uneven light asymmetric.
        """
        omega = self._kappa * self._orders[1:]  # (M,)
        if xs.shape[1] == 1:
            mids, halves = xs, np.zeros_like(xs)
        else:
            mids, halves = 0.5 * (xs[:, 1:] + xs[:, :-1]), 0.5 * (xs[:, 1:] - xs[:, :-1])
        icfg = self.config.illumination
        ones, zeros = np.ones((xs.shape[0], 1)), np.zeros((xs.shape[0], 1))
        total = np.zeros((xs.shape[0], self._matrix.shape[1]))
        for xm, h in zip(mids.T, halves.T):
            wh = h[:, None] * omega
            arg = xm[:, None] * omega
            cos, sin = np.cos(arg), np.sin(arg)
            damp = np.sinc(wh / math.pi)
            if focus is not None:
                damp = damp * focus
            basis = np.concatenate([ones, cos * damp, sin * damp], axis=1)
            light = basis @ self._matrix
            if icfg.has_target_field:
                curv = icfg.gradient_curvature_per_mm2
                slope = (icfg.gradient_per_mm + 2 * curv * (xm - icfg.gradient_center_mm))[:, None]
                small = np.abs(wh) < 1e-3
                safe_h = np.where(small, 1.0, h[:, None] * np.ones_like(wh))
                moment = np.where(small, wh * h[:, None] / 3,
                                  (np.sin(wh) - wh * np.cos(wh)) / (omega * omega * safe_h))
                if focus is not None:
                    moment = moment * focus
                drift = np.concatenate([zeros, -sin * moment, cos * moment], axis=1)  # e^{jωx_m}·j·moment
                light *= illum.target_field_gain(icfg, xm)[:, None]
                light += slope * (basis @ self._matrix_s[0] + drift @ self._matrix)
                light += curv * (basis @ self._matrix_s[1] + 2 * (drift @ self._matrix_s[0]))
            total += light
        return total / mids.shape[1]

    def _light_slow(self, xs: np.ndarray, t: np.ndarray, focus: np.ndarray | None = None) -> np.ndarray:
        """Chirp, target-fixed gains or a growing print: evaluate every pixel at sub-samples of each
        exposure. A growing print is taken at each frame's mid-exposure ``t`` (it grows over seconds).
        ``focus`` as for :meth:`_light_fast`; defects keep the base blur (their widening by a drift
        of a fraction of a pixel is far below what they do to the profile)."""
        points = self._subsamples(xs)  # (K, Q)
        R, n = self.n_rows, self.n_pixels
        acc = np.zeros((xs.shape[0], R, n))
        tcfg, icfg = self.config.target, self.config.illumination
        blur = self.config.optics.defocus_sigma_mm
        aperture = self.pixel_pitch_mm  # a pixel's footprint on the target (fill factor 1)
        t_frame = t[:, None, None] if tcfg.growths else None
        offsets = self.geometry.x_mm  # (R, n), or (K, R, n) while the magnification drifts or after a knock
        if self.config.optics.moves:
            offsets = drifted_offsets(self.config.optics, offsets, t, self.geometry.y_mm)
        for q in range(points.shape[1]):
            xq = points[:, q]
            if tcfg.affine and not tcfg.growths and offsets.ndim == 2:
                basis = self._basis(self._kappa * xq)
                if focus is not None:
                    basis[:, 1:] *= np.tile(focus, 2)
                light = (basis @ self._matrix).reshape(-1, R, n)
            else:
                theta = tgt.phase(tcfg, xq[:, None, None] + offsets, t_frame)  # (K, R, n)
                z = np.exp(1j * theta)
                zi = np.ones_like(z)
                light = np.broadcast_to(self._coeffs[0].real, z.shape).copy()
                for i, c in enumerate(self._coeffs[1:]):
                    zi = zi * z
                    light += (c * zi).real if focus is None else (c * zi).real * focus[:, i, None, None]
            x_w = xq[:, None, None] + offsets
            if icfg.has_target_field:
                light *= illum.target_field_gain(icfg, x_w)
            if tcfg.defects:  # printed on the target: they move with it when it grows
                x_print = tgt.printed_coordinate(tcfg, x_w, t_frame)
                for r in range(R):
                    light[:, r] *= tgt.defect_gain(tcfg.defects, x_print[:, r], float(self._row_y[r]), blur, aperture,
                                                   t)
            acc += light
        return acc / points.shape[1]

    def _subsamples(self, xs: np.ndarray) -> np.ndarray:
        """Midpoints of equal sub-intervals of each piecewise-linear exposure, fine enough that
        neither a period nor a defect is smeared between samples."""
        if xs.shape[1] == 1:
            return xs
        scale = self.config.target.true_period_mm / 256
        sizes = [d.size_mm for d in self.config.target.defects]
        if sizes:
            scale = min(scale, min(sizes) / 4)
        seg = np.abs(np.diff(xs, axis=1)).max()
        m = int(min(max(math.ceil(seg / scale), 1), 64))
        frac = (np.arange(m) + 0.5) / m
        pieces = xs[:, :-1, None] + (xs[:, 1:] - xs[:, :-1])[:, :, None] * frac
        return pieces.reshape(xs.shape[0], -1)

    # ----- recording ------------------------------------------------------------------------
    def record(self, seconds: float | None = None, trajectory: Trajectory | None = None,
               progress: ProgressCallback | None = None) -> tuple[Recording, Truth]:
        """Record ``seconds`` of frames while the stage follows ``trajectory``.

        Default trajectory: the scenario's sweep (:meth:`default_trajectory`) filling ``seconds``.
        Returns the recording (what a real rig would write) and the ground truth beside it.
        """
        cfg = self.config
        seconds = cfg.default_seconds if seconds is None else float(seconds)
        if not seconds > 0:
            raise ValueError(f"seconds must be positive, got {seconds}")
        trajectory = self.default_trajectory(seconds) if trajectory is None else trajectory
        stage = cfg.stage
        if stage.vibration_mm:
            trajectory = Vibrating(trajectory, stage.vibration_mm, stage.vibration_hz, stage.vibration_phase_rad)
        clock = frame_clock(cfg.timing, seconds, self._timing_rng)
        keep = np.flatnonzero(clock.kept)
        # a driver that delivers the previous image again, with a new timestamp (and reference)
        shown = np.arange(keep.size)
        if cfg.timing.duplicate_probability:
            again = self._duplicate_rng.random(keep.size) < cfg.timing.duplicate_probability
            again[0] = False
            shown = np.maximum.accumulate(np.where(again, 0, shown))
        t_mid = clock.exposure_mid[keep][shown]
        T = self.exposure_s
        v_mid = np.asarray(trajectory.velocity(t_mid), dtype=np.float64)
        moving = T > 0 and float(np.max(np.abs(v_mid))) * T > 1e-9
        # a vibration is followed through the exposure: enough samples per cycle for the piecewise-
        # linear motion to integrate it (constant velocity needs only the ends and the middle)
        pieces = 2 if not stage.vibration_mm else max(2, 2 * math.ceil(8 * stage.vibration_hz * T))
        offsets = np.linspace(-0.5, 0.5, pieces + 1) * T if moving else np.zeros(1)
        x_samples = np.asarray(trajectory.position(t_mid[:, None] + offsets), dtype=np.float64)
        frames = np.empty((keep.size, self.n_rows, self.n_pixels), dtype=self.frame_dtype)
        step = max(1, 4 * CHUNK_ELEMENTS // (self.n_rows * self.n_pixels))
        for k0 in range(0, keep.size, step):
            k1 = min(k0 + step, keep.size)
            frames[k0:k1] = self.render(x_samples[k0:k1], t_mid[k0:k1])
            if progress is not None:
                progress(k1 / keep.size, f"frame {k1}/{keep.size}")
        duplicated = shown != np.arange(keep.size)
        if duplicated.any():  # the very same image (and noise) as the frame it repeats
            frames[duplicated] = frames[shown[duplicated]]
        reference = self.make_grating(trajectory).read(clock.latch[keep])
        x_mid = np.asarray(trajectory.position(t_mid), dtype=np.float64)
        x_mean = x_samples.mean(axis=1) if x_samples.shape[1] == 1 else (
            0.5 * (x_samples[:, 1:] + x_samples[:, :-1]).mean(axis=1)  # trapezoid over the exposure
        )
        stored = frames[:, 0, :] if self.n_rows == 1 else frames
        meta = self.meta()
        # what the owner commanded of the stage (a vibration riding on it is the rig's, not a command)
        commanded = trajectory.base if isinstance(trajectory, Vibrating) else trajectory
        peak = getattr(commanded, "peak_acceleration_mm_s2", None)
        if peak is not None and peak > 0:
            meta[STAGE_ACCELERATION] = float(peak)
        if hasattr(commanded, "acceleration_phases"):  # when, not only how hard: the plan's phases
            meta[STAGE_PHASES] = [[round(t0, 9), round(t1, 9), float(a)]
                                  for t0, t1, a in commanded.acceleration_phases()]
        rec = Recording(stored, clock.stamp[keep], reference, meta)
        info = {"scenario": cfg.scenario, "effects": list(cfg.effects), "seed": self.seed,
                "config": _jsonable(asdict(cfg))}
        if self.camera_side is not None:
            info["camera_side"] = self.camera_side.truth()
        truth = Truth(
            t_s=t_mid,
            x_mm=x_mid,
            v_mm_s=v_mid,
            x_mean_mm=x_mean,
            reference_error_mm=reference - x_mid,
            light_gain=illum.flicker_gain(cfg.illumination, t_mid, T) * illum.level_change(cfg.illumination, t_mid)[0],
            frame_index=keep,
            pixel_x_mm=self.geometry.x_mm.copy(),
            pixel_gain=self.sensor.prnu * self._vignetting * cfg.sensor.gain,
            pixel_offset_gray=self.sensor.dsnu + cfg.sensor.black_level_gray,
            period_mm=cfg.target.true_period_mm,
            noise_gray=cfg.sensor.read_noise_gray,
            info=info,
        )
        return rec, truth

    def meta(self) -> dict[str, Any]:
        """Recording metadata: what the rig's owner knows (nominal figures), never the truth."""
        cfg = self.config
        meta: dict[str, Any] = {
            "pixel_pitch_mm": self.pixel_pitch_mm,
            "period_mm": self.period_mm,
            "source": "sim",
            "scenario": cfg.scenario,
            "effects": list(cfg.effects),
            "seed": self.seed,
            "frame_rate_hz": cfg.timing.frame_rate_hz,
            "exposure_s": cfg.timing.exposure_s,
            "grating_resolution_mm": cfg.grating.resolution_mm,
            "gray_scale": "8-bit equivalent" if cfg.sensor.bit_depth is None else f"{cfg.sensor.bit_depth}-bit",
            # the virtual camera exposes on the frame clock that latches the grating, unless it runs on its own
            # (the `clock_drift` effect)
            CAMERA_TRIGGER: "free-run" if cfg.timing.clock_ppm else "hardware",
        }
        if cfg.sensor.bit_depth is not None:
            meta["bit_depth"] = cfg.sensor.bit_depth
        elif cfg.sensor.clip:  # a float camera that clips at full scale states it (its bit depth does not)
            meta[SENSOR_RANGE] = [0.0, FULL_SCALE_GRAY]
        return meta


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value
