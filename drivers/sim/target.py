"""The printed target: its gray profile along x, the pitch of the print, and local defects.

The target's profile is periodic in a *phase* ``θ = 2π w(x_w) / τ_true`` where ``x_w`` is the target
coordinate, ``τ_true = τ_nominal·(1 + scale error)`` the printed period and ``w(x) = x + chirp(x)``
a slow nonlinear warp of the print (pitch error that is not a pure scale). Along one period the
profile is a short Fourier series, ``Re Σ_i C_i e^{jiθ}``; keeping it in this form is what makes
rendering fast (see ``rig.py``) and lets print distortions (harmonics, print gamma) and optical
blur be applied as exact operations on the coefficients.

The coefficients may differ from pixel to pixel: the ``paper`` scene is the seed paper's Table 2
gray field, whose Fourier coefficients are cubics in the pixel index u — it describes a whole rig
(target, light and camera) rather than the print alone. A plain ``sine`` scene has the same
coefficients for every pixel.

The print may also change size after calibration (paper in humidity, a film warming up):
:class:`Growth` stretches the target about a fixed point by a factor that may ramp in time. It moves
every printed feature (the profile and the defects) and nothing else: the light falls where it did
and the stage's own grating does not see it. A camera calibrated before the growth then reads a
position off by ``−g·(x − c)``: a scale error against the grating, and an offset wherever the view
is not centred on the fixed point.

Defects (dust, scratches) are local and two-dimensional (they depend on the row's y as well), so
they are not part of the Fourier series; they are a multiplicative gain fixed to the target
(:func:`defect_gain`), combined with the illumination field fixed to the target.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from graytrack.drivers.sim import paper


@dataclass
class Defect:
    """A local print defect: Gaussian profile, relative ``depth`` (positive darkens, negative brightens).

    ``kind="dust"`` is a round spot of standard deviation ``size_mm`` centred at (x, y);
    ``kind="scratch"`` is a line through (x, y) at ``angle_rad`` from the target's y axis with
    Gaussian cross-section of standard deviation ``size_mm``. ``start_s``: the run time from which
    it is on the print (dust settling during a run); before it the print there is clean.
    """

    kind: str
    x_mm: float
    y_mm: float
    size_mm: float
    depth: float
    angle_rad: float = 0.0
    start_s: float = 0.0


@dataclass
class Growth:
    """The print grows by ``ppm`` (parts per million) about target coordinate ``center_mm``: from
    ``start_s`` on, reached linearly over ``ramp_s`` (0: a step)."""

    ppm: float
    center_mm: float
    start_s: float = 0.0
    ramp_s: float = 0.0

    def relative(self, t_s: np.ndarray) -> np.ndarray:
        """The growth ``g(t)`` (dimensionless) at time(s) ``t_s``."""
        t = np.asarray(t_s, dtype=np.float64)
        if self.ramp_s > 0:
            done = np.clip((t - self.start_s) / self.ramp_s, 0.0, 1.0)
        else:
            done = (t >= self.start_s).astype(np.float64)
        return self.ppm * 1e-6 * done


@dataclass
class TargetConfig:
    """What is printed and how well. ``period_mm`` is the nominal (design) period."""

    kind: str = "sine"  # "sine": A sin(θ + φ) + D for every pixel; "paper": Table 2 field
    period_mm: float = 8.62
    amplitude_gray: float = 80.0
    offset_gray: float = 128.0
    phase_rad: float = 0.0
    harmonics: list[tuple[int, float, float]] = field(default_factory=list)  # (order, rel. amplitude, phase rad)
    print_gamma: float = 1.0
    scale_error: float = 0.0  # printed period = nominal · (1 + scale_error)
    chirp_mm: float = 0.0  # peak nonlinear pitch error over the chirp span
    chirp_order: int = 2  # shape of the warp: ξ^order on ξ ∈ [-1, 1]
    chirp_center_mm: float = 8.0
    chirp_half_span_mm: float = 10.0
    defects: list[Defect] = field(default_factory=list)
    growths: list[Growth] = field(default_factory=list)  # applied in order, after calibration-time printing

    @property
    def true_period_mm(self) -> float:
        return self.period_mm * (1.0 + self.scale_error)

    @property
    def affine(self) -> bool:
        """True when the phase is linear in x (no chirp): the fast rendering path applies."""
        return self.chirp_mm == 0.0


def warp_mm(cfg: TargetConfig, x_w: np.ndarray) -> np.ndarray:
    """``w(x) = x + chirp(x)``: where along an ideal print the point x_w really lies."""
    if cfg.chirp_mm == 0.0:
        return x_w
    xi = (x_w - cfg.chirp_center_mm) / cfg.chirp_half_span_mm
    return x_w + cfg.chirp_mm * xi**cfg.chirp_order


def printed_coordinate(cfg: TargetConfig, x_w: np.ndarray, t_s: np.ndarray | None) -> np.ndarray:
    """Where on the print as it was made lies the point now at target coordinate ``x_w``.

    ``t_s`` broadcasts against ``x_w`` (one time per frame: ``(K, 1, 1)`` for ``(K, R, n)``); each
    growth ``x → c + (x − c)(1 + g)`` is undone in reverse order. No growth or no time: ``x_w``.
    """
    x = np.asarray(x_w, dtype=np.float64)
    if not cfg.growths or t_s is None:
        return x
    for growth in reversed(cfg.growths):
        x = growth.center_mm + (x - growth.center_mm) / (1.0 + growth.relative(t_s))
    return x


def phase(cfg: TargetConfig, x_w: np.ndarray, t_s: np.ndarray | None = None) -> np.ndarray:
    """Target phase θ at target coordinate(s) ``x_w`` (rad), at time(s) ``t_s`` when the print grows."""
    return 2 * math.pi * warp_mm(cfg, printed_coordinate(cfg, x_w, t_s)) / cfg.true_period_mm


def fourier_coefficients(cfg: TargetConfig, u: np.ndarray, n_orders: int = 8) -> np.ndarray:
    """Complex coefficients ``C`` of shape ``(M+1, *u.shape)``: profile = ``Re Σ_i C_i e^{jiθ}``.

    ``u`` is the pixel index seen by each pixel (the ``paper`` field depends on it). Harmonics and
    print gamma are applied here; ``n_orders`` bounds the orders that print gamma may create.
    """
    u = np.asarray(u, dtype=np.float64)
    if cfg.kind == "paper":
        powers = np.stack([np.ones_like(u), u, u**2, u**3], axis=-1)
        sin_c = np.moveaxis(powers @ paper.SIN_COEFFS.T, -1, 0)  # a_i(u)
        cos_c = np.moveaxis(powers @ paper.COS_COEFFS.T, -1, 0)  # b_i(u)
        # a sin + b cos = Re[(b - j a) e^{jθ}]
        coeffs = np.concatenate([(powers @ paper.OFFSET_COEFFS)[None].astype(complex), cos_c - 1j * sin_c])
    elif cfg.kind == "sine":
        coeffs = np.zeros((2,) + u.shape, dtype=complex)
        coeffs[0] = cfg.offset_gray
        coeffs[1] = -1j * cfg.amplitude_gray * np.exp(1j * cfg.phase_rad)  # A sin(θ+φ)
    else:
        raise ValueError(f"unknown target kind {cfg.kind!r}")
    for order, rel_amp, ph in cfg.harmonics:
        coeffs = _add_harmonic(coeffs, int(order), float(rel_amp), float(ph))
    if cfg.print_gamma != 1.0:
        coeffs = _apply_gamma(coeffs, cfg.print_gamma, max(n_orders, coeffs.shape[0] - 1))
    return coeffs


def _add_harmonic(coeffs: np.ndarray, order: int, rel_amp: float, ph: float) -> np.ndarray:
    """Add ``rel_amp·A·sin(order·(θ+φ) + ph)`` where A, φ are each pixel's fundamental."""
    if order < 2:
        raise ValueError(f"harmonic order must be ≥ 2, got {order}")
    if coeffs.shape[0] <= order:
        coeffs = np.concatenate([coeffs, np.zeros((order + 1 - coeffs.shape[0],) + coeffs.shape[1:], complex)])
    c1 = coeffs[1]
    amp = np.abs(c1)
    unit = np.where(amp > 0, c1 / np.where(amp > 0, amp, 1), 0)  # -j e^{jφ}
    # -j A e^{j(kφ+ph)} = A · unit^k · (-j)^(1-k) · e^{j ph}
    coeffs[order] = coeffs[order] + rel_amp * amp * unit**order * (-1j) ** (1 - order) * np.exp(1j * ph)
    return coeffs


def _apply_gamma(coeffs: np.ndarray, gamma: float, n_orders: int) -> np.ndarray:
    """Print gamma: each pixel's profile, normalised to [0, 1] over a period, raised to ``gamma``.

    Done numerically on 8·(M+1) samples per period and brought back to Fourier coefficients by FFT;
    the series is truncated at ``n_orders``, which is where a real print's dot gain stops mattering.
    """
    n_samples = 8 * (n_orders + 1)
    theta = 2 * np.pi * np.arange(n_samples) / n_samples
    orders = np.arange(coeffs.shape[0])
    basis = np.exp(1j * orders[:, None] * theta[None, :])  # (M+1, N)
    profile = np.real(np.tensordot(basis, coeffs, axes=(0, 0)))  # (N, ...)
    lo, hi = profile.min(axis=0), profile.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    shaped = lo + span * ((profile - lo) / span) ** gamma
    spectrum = np.fft.fft(shaped, axis=0) / n_samples
    out = spectrum[: n_orders + 1].copy()
    out[1:] *= 2  # real signal: Re Σ C_i e^{jiθ} with C_i = 2·X_i for i ≥ 1
    out[0] = out[0].real
    return out


def defect_gain(defects: list[Defect], x_w: np.ndarray, y_mm: float, blur_sigma_mm: float = 0.0,
                aperture_mm: float = 0.0, t_s: np.ndarray | None = None) -> np.ndarray:
    """Multiplicative gain of the defects along a line of constant y (the row's y on the target),
    as a pixel of footprint ``aperture_mm`` (square, on the target) centred at each ``x_w`` sees it.

    Optical blur (defocus) widens each Gaussian defect and lowers its peak exactly as a Gaussian
    convolution does: σ² → σ² + σ_b², depth × σ/σ' per blurred dimension. A pixel then averages the
    light over its footprint: a defect narrower than a pixel is a box-smoothed step in x_w, never a
    spike its centre alone would see (a real sensor has no point pixels; a model would otherwise be
    asked for detail no camera delivers). ``t_s`` (one time per frame, the first axis of ``x_w``):
    a defect is there only on the frames from its ``start_s`` on (without times: always).
    """
    gain = np.ones_like(x_w, dtype=np.float64)
    half = 0.5 * max(float(aperture_mm), 0.0)
    for d in defects:
        s = math.hypot(d.size_mm, blur_sigma_mm)
        shrink = d.size_mm / s
        if d.kind == "dust":
            depth = d.depth * shrink**2 * _box_mean(y_mm - d.y_mm, s, half)
            x_centre, sx = d.x_mm, s
        elif d.kind == "scratch":
            depth = d.depth * shrink
            x_centre, sx = d.x_mm + (y_mm - d.y_mm) * math.tan(d.angle_rad), s / math.cos(d.angle_rad)
        else:
            raise ValueError(f"unknown defect kind {d.kind!r}")
        # a Gaussian is nil beyond 8σ (and half a footprint): evaluate only the pixels near the defect
        near = np.abs(x_w - x_centre) < 8 * sx + half
        if d.start_s > 0.0 and t_s is not None:
            arrived = np.asarray(t_s, dtype=np.float64) >= d.start_s
            near &= arrived.reshape(arrived.shape + (1,) * (near.ndim - arrived.ndim))
        if depth and near.any():
            gain[near] *= 1 - depth * _box_mean(x_w[near] - x_centre, sx, half)
    return gain


def _box_mean(offset, sigma: float, half: float):
    """The mean of ``exp(−u²/2σ²)`` over ``u ∈ offset ± half`` (``half = 0``: the value at ``offset``)."""
    if half <= 0.0:
        return np.exp(-np.square(offset) / (2 * sigma * sigma))
    from scipy.special import ndtr

    scale = sigma * math.sqrt(2 * math.pi) / (2 * half)
    return scale * (ndtr((np.asarray(offset) + half) / sigma) - ndtr((np.asarray(offset) - half) / sigma))
