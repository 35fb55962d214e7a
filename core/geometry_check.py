"""Geometry sanity: does a fitted model describe the images, and if not, is the rig set up wrong?

A least-squares fit always returns *a* model. When the camera's pixel axis runs against the
target coordinate (the camera mounted the other way round, ReverseX on), when part of the ROI
looks past the print, or when the configured period is far off, the fit still converges, to a
model that leaves a residual many times the noise (or silently absorbs the fault), and tracking
with it is wrong by hundreds of µm. The fault is in the rig's set-up, not in the model, and no
model term should "fix" it, so it is looked for here, once, after the fit, with cheap comparisons:

* the residual against the model-free noise (core/noise.py): √χ² of the calibration;
* the pixel direction: the same plain model fitted with the pixel axis reversed (frames[..., ::-1]),
  and the model-free sign of the phase rate across the line (the target shift per pixel);
* the ROI on the target: every pixel's modulation at the fitted period along the stroke;
* the fitted period and the model-free pixel footprint against the configured (nominal) ones,
  and the fitted period against the one the images show without a model.

The verdict is ``ok``, ``doubtful`` (a warning with its likely cause: the model is usable) or
``refused`` (a cause that makes the model wrong, named with its fix in one line).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from graytrack.core.calibration_data import CalibrationData
from graytrack.core.errors import CalibrationError, GraytrackError
from graytrack.core.geometry import estimate_period, fundamental_phase, initial_geometry, phase_rate_mm
from graytrack.core.models.fourier import FourierModel
from graytrack.core.recording import PIXEL_AXIS_REVERSED, Recording
from graytrack.core.structure import ModelSpec, fit_spec

STATUSES = ("ok", "doubtful", "refused")
CAUSES = ("pixel_direction", "roi_off_target", "period", "pitch", "residual")
SET_UP_FAULTS = ("pitch",)  # found with a far residual, these refuse the model
# √χ² of the calibration beyond which the residual is called far above the noise. The seed
# paper's model leaves ≤ 1.02 on the paper rigs and 1.8–2.7 on the lab bench (print gamma,
# defocus, dust: terms the closed loop adds); a reversed pixel axis leaves 30–41.
RESIDUAL_DOUBT = 3.0
# The reversed axis fits this many times better (rms, the same plain model): the axis is reversed.
FLIP_GAIN = 2.0
# Frames used by the orientation fits (a subsample of the sweep: the comparison is by a factor).
ORIENTATION_FRAMES = 400
# Fitted τ_w this far from the configured one is said (a print's scale error is ≤ 0.1 %).
PERIOD_TOLERANCE = 0.02
# The fit's period this far from the images' (read without a model, to a few % over a stroke of one
# or two periods): it landed on another period (a multiple) than the print's.
PERIOD_MISMATCH = 0.10
PITCH_TOLERANCE = 0.10  # α·d: pixel polynomials trade with it, and a lens refocus moves it by %
# A pixel modulated by less than this share of the line's typical pixel sees no print …
OFF_TARGET_MODULATION = 0.2
# … and when such pixels make up this share of the ROI, the ROI is (partly) off the target.
OFF_TARGET_SHARE = 0.1
# A model that uses less than this share of the ROI's pixels (the rest masked) describes too little.
MIN_SEEN_SHARE = 0.2


class GeometryError(CalibrationError):
    """A calibration refused for a fault of the rig's geometry; ``check`` says which."""

    def __init__(self, check: "GeometryCheck") -> None:
        super().__init__(check.message)
        self.check = check


def raise_if_refused(check: "GeometryCheck | None") -> None:
    """:class:`GeometryError` with the cause and its fix when ``check`` refused the rig."""
    if check is not None and check.refused:
        raise GeometryError(check)


@dataclass(frozen=True)
class GeometryCheck:
    """The verdict on a fit's geometry, with the figures it rests on (JSON-ready)."""

    status: str = "ok"  # one of STATUSES
    cause: str | None = None  # one of CAUSES (None when ok)
    message: str = ""  # one line: the cause and the fix
    residual_ratio: float = float("nan")  # rms residual over the noise (√χ²)
    flipped_gain: float | None = None  # rms with the axis as given over rms reversed (None: not tried)
    phase_rate_mm: float | None = None  # model-free target shift per pixel (negative: reversed axis)
    period_mm: float = float("nan")
    nominal_period_mm: float | None = None
    pixel_pitch_mm: float = float("nan")
    nominal_pitch_mm: float | None = None
    off_target_share: float = 0.0
    off_target: str = ""  # which pixels/rows see no print
    data_period_mm: float | None = None  # the period the images show, model-free (when the fit's was doubted)
    warnings: tuple[str, ...] = field(default_factory=tuple)

    @property
    def refused(self) -> bool:
        return self.status == "refused"

    def as_dict(self) -> dict[str, Any]:
        body = asdict(self)
        body["warnings"] = list(self.warnings)
        return {key: (None if isinstance(value, float) and not math.isfinite(value) else
                      round(value, 6) if isinstance(value, float) else value) for key, value in body.items()}


def residual_ratio(model: FourierModel, rmse_gray: float | None = None, sigma_gray: float | None = None) -> float:
    """√χ² of the calibration: the rms residual in units of the noise (photon transfer included)."""
    chi2 = model.info.get("calibration_chi2")
    if chi2 is not None and math.isfinite(float(chi2)):
        return math.sqrt(max(float(chi2), 0.0))
    rmse = rmse_gray if rmse_gray is not None else model.info.get("calibration_rmse_gray")
    sigma = sigma_gray if sigma_gray is not None else model.noise_gray
    if rmse is None or not sigma:
        return float("nan")
    return float(rmse) / float(sigma)


def refusal(model: FourierModel) -> str | None:
    """Why the model's own calibration refused its geometry (None: it did not, or was not checked)."""
    check = model.info.get("geometry")
    if isinstance(check, dict) and check.get("status") == "refused":
        return str(check.get("message") or check.get("cause") or "geometry refused")
    return None


def flipped(data: CalibrationData) -> CalibrationData:
    """The data with the pixel axis reversed (what ``--flip`` and ``[camera] flip`` do to frames)."""
    return replace(data, frames=data.frames[..., ::-1], weights=data.weights[..., ::-1])


def check_geometry(data: CalibrationData, model: FourierModel, rmse_gray: float | None = None) -> GeometryCheck:
    """Judge a model fitted to ``data``: ok, doubtful (warnings) or refused, with the likely cause."""
    ratio = residual_ratio(model, rmse_gray, data.sigma_gray)
    nominal_period = _positive(data.meta.get("period_mm"))
    nominal_pitch = _positive(data.meta.get("pixel_pitch_mm"))
    dark = dark_pixels(data, model.period_mm)
    rate = _phase_rate(data.x_mm, data.frames.mean(axis=1), model.period_mm, dark.mean(axis=0) < 0.5)
    base = GeometryCheck(residual_ratio=ratio, phase_rate_mm=rate, period_mm=model.period_mm,
                         nominal_period_mm=nominal_period, pixel_pitch_mm=model.pixel_pitch_mm,
                         nominal_pitch_mm=nominal_pitch)
    far = not ratio <= RESIDUAL_DOUBT  # NaN counts as far: nothing vouches for the model
    if far or (rate is not None and rate < 0):
        gain = orientation_gain(data)
        base = replace(base, flipped_gain=gain)
        if gain is not None and gain >= FLIP_GAIN:
            fix = ("the frames were reversed already (--flip or [camera] flip = true): leave it out"
                   if data.meta.get(PIXEL_AXIS_REVERSED) is True else "use --flip or [camera] flip = true")
            return replace(base, status="refused", cause="pixel_direction", message=(
                f"the pixel axis looks reversed: the residual is {ratio:.1f}x the noise and the fit is {gain:.1f}x "
                f"better with the axis reversed; {fix}"))
    nominal, data_period, wrong_period = _nominal_findings(data, model, rate, nominal_period, nominal_pitch, far)
    base = replace(base, data_period_mm=data_period)
    if wrong_period is not None:
        return replace(base, status="refused", cause="period", message=wrong_period)
    share, where = off_target(dark)
    base = replace(base, off_target_share=share, off_target=where)
    findings: list[tuple[str, str]] = []
    # What sees the print and what the fit did not set aside: too little of the ROI to call a model.
    # (A part of the ROI off the print is no refusal by itself: its pixels are set aside as dead ones,
    # by calibrate's screen or the loop's bad-pixel step, and the rest measures at its own bound.)
    usable = min(float(np.mean(model.seen())), 1.0 - share)
    if usable < MIN_SEEN_SHARE:
        where_text = f"{where} see no period" if where else "most pixels were set aside"
        return replace(base, status="refused", cause="roi_off_target", message=(
            f"the model can use {usable:.0%} of the ROI's pixels ({where_text}): the ROI is off the target; "
            f"move it onto the print ([camera.roi])"))
    if share >= OFF_TARGET_SHARE:
        findings.append(("roi_off_target", f"{where} ({share:.0%} of the ROI) see no period: the ROI is partly off "
                                           f"the target; move it onto the print ([camera.roi])"))
    findings.extend(nominal)
    if far:
        residual = f"the residual is {ratio:.1f}x the noise"
        faults = [(cause, text) for cause, text in findings if cause in SET_UP_FAULTS]
        if faults:  # a fault of the set-up found: the model is wrong, not merely too simple
            cause, text = faults[0]
            return replace(base, status="refused", cause=cause, message=f"{residual}: {text}",
                           warnings=tuple(t for c, t in findings if (c, t) != faults[0]))
        stream = model.info.get("stream")
        findings.append(("residual", f"{residual}: the frames' JPEG quantisation (quality ~{stream['quality']}), "
                                     "which no model describes" if stream else
                                     f"{residual}: the model misses much of what the images show "
                                     f"(graytrack diagnose looks for what)"))
    if not findings:
        return base
    cause, text = findings[0]
    return replace(base, status="doubtful", cause=cause, message=text, warnings=tuple(t for _, t in findings))


def _nominal_findings(data: CalibrationData, model: FourierModel, rate: float | None, nominal_period: float | None,
                      nominal_pitch: float | None, far: bool) -> tuple[list[tuple[str, str]], float | None, str | None]:
    """The configured τ_w and α·d against the fit and the images: (findings, the model-free period
    when it was read, a refusal's text when the fit landed on another period than the images show).

    A fitted τ_w far from the configured one has three readings. The images, read without a model,
    agree with the fit and the residual is at the noise: the configuration was wrong and the fit
    corrected it (a warning: fix the configuration). The images show a third period (the fit
    landed on a multiple of it): refused. The residual is far above the noise: something the model
    lacks pulls the geometry (an ink smudge drags τ_w by 5 %, and with a stroke of one or two
    periods the model-free reading as well), which the closed loop deals with: a doubt, not a
    set-up fault. α·d is compared by the phase rate across the line, read without a model."""
    findings: list[tuple[str, str]] = []
    data_period = None
    if nominal_period is not None and abs(model.period_mm / nominal_period - 1.0) > PERIOD_TOLERANCE:
        try:
            data_period = estimate_period(data.x_mm, data.frames.mean(axis=1), data.stroke_mm)
        except GraytrackError:
            data_period = None
        fitted = f"the fitted period {model.period_mm:.4f} mm is {model.period_mm / nominal_period - 1.0:+.1%} " \
                 f"from the configured {nominal_period:.4f} mm"
        if far:
            findings.append(("residual", f"{fitted}: something the model lacks pulls the geometry (a print defect, "
                                         f"uneven light: graytrack diagnose), or period_mm is wrong"))
        elif data_period is not None and abs(model.period_mm / data_period - 1.0) > PERIOD_MISMATCH:
            return findings, data_period, (
                f"the images show a period of {data_period:.4f} mm, the configuration says {nominal_period:.4f} mm "
                f"and the fit landed on {model.period_mm:.4f} mm; set period_mm to the printed period "
                f"(recording meta or [sweep] period_mm)")
        else:
            seen = "" if data_period is None else f" (the images without a model: {data_period:.4f} mm)"
            findings.append(("period", f"{fitted}{seen}: the fit corrected it; set period_mm to the printed period "
                                       f"(recording meta or [sweep] period_mm)"))
    if nominal_pitch is not None and rate is not None and abs(abs(rate) / nominal_pitch - 1.0) > PITCH_TOLERANCE:
        findings.append(("pitch", f"the images show a pixel footprint of {abs(rate) * 1e3:.2f} um, "
                                  f"{abs(rate) / nominal_pitch - 1.0:+.1%} from the configured "
                                  f"{nominal_pitch * 1e3:.2f} um (the fit: {model.pixel_pitch_mm * 1e3:.2f} um); "
                                  f"check the lens and set pixel_pitch_mm"))
    return findings, data_period, None


def orientation_mismatch(model: FourierModel, rec: Recording, frames_used: int = 64) -> float | None:
    """rms of a recording's frames against the model at the grating's positions, as given over
    reversed: ≫ 1 when the frames run the other way than the model's (a camera remounted since
    calibration, ReverseX toggled, ``--flip`` given twice or forgotten). None without a reference.

    Up to ``frames_used`` frames spread over the run, the model's light as calibrated: a factor
    between two orientations, not a figure of either, is what it tells."""
    valid = np.flatnonzero(np.isfinite(rec.reference))
    if valid.size < 10 or rec.n_pixels != model.n_pixels:
        return None
    pick = valid[np.linspace(0, valid.size - 1, min(frames_used, valid.size)).round().astype(int)]
    picked = rec.frames[pick].astype(np.float64)  # only the frames used, as Recording.strip() gives them
    strip = picked[:, None, :] if picked.ndim == 2 else picked
    predicted = model.predict(rec.reference[pick])
    seen = model.seen()  # masked pixels left out (broadcast over frames and rows)

    def rms(frames: np.ndarray) -> float:
        return float(np.sqrt((((frames - predicted) * seen) ** 2).mean()))

    return rms(strip) / max(rms(strip[..., ::-1]), 1e-12)


def orientation_gain(data: CalibrationData) -> float | None:
    """rms of the plain paper model with the pixel axis as given over the same with it reversed.

    Both fits see the same subsample of the row-mean line, so the cost is two small fits however
    large the sweep; a factor between them is what matters, not either figure. None when either
    fit is refused by the data (too few frames, no period)."""
    line = data.frames.mean(axis=1, keepdims=True)
    usable = data.weights.min(axis=1, keepdims=True)
    small = replace(data, frames=line, weights=usable, pixel_noise=None)
    if len(small.x_mm) > ORIENTATION_FRAMES:
        small = small.subset(np.linspace(0, len(small.x_mm) - 1, ORIENTATION_FRAMES).round().astype(int))
    spec = ModelSpec(harmonics=5, pixel_degree=min(3, max(line.shape[-1] // 10 - 1, 0)), name="orientation")
    rms = []
    for candidate in (small, flipped(small)):
        try:
            period, pitch, _ = initial_geometry(candidate)
            rms.append(fit_spec(spec, candidate, period, pitch).rmse_gray)
        except GraytrackError:
            return None
    return float(rms[0] / max(rms[1], 1e-12))


def dark_pixels(data: CalibrationData, period_mm: float) -> np.ndarray:
    """``(R, n)`` True for pixels that see no period along the stroke (past the print, or dead).

    Each pixel's modulation is its fundamental's amplitude at the fitted period; the line's
    typical pixel (90th percentile, so that a dim end of a vignetted line counts as lit) sets the
    scale, and pixels below OFF_TARGET_MODULATION of it see no print."""
    k, rows, n = data.frames.shape
    theta = 2.0 * math.pi * data.x_mm / period_mm
    design = np.stack([np.sin(theta), np.cos(theta), np.ones_like(theta)], axis=1)
    coef, *_ = np.linalg.lstsq(design, data.frames.reshape(k, -1), rcond=None)
    modulation = np.hypot(coef[0], coef[1]).reshape(rows, n)
    return modulation < OFF_TARGET_MODULATION * float(np.percentile(modulation, 90))


def off_target(dark: np.ndarray) -> tuple[float, str]:
    """(share of the ROI's pixels that see no period, which ones in words) from :func:`dark_pixels`."""
    if not dark.any():
        return 0.0, ""
    share = float(dark.mean())
    dark_rows = np.flatnonzero(dark.all(axis=1))
    if dark.shape[0] > 1 and dark_rows.size:
        return share, f"rows {_ranges(dark_rows)}"
    columns = np.flatnonzero(dark.mean(axis=0) >= 0.5)
    return share, f"pixels {_ranges(columns)}" if columns.size else f"{int(dark.sum())} pixels"


def _phase_rate(x_mm: np.ndarray, line: np.ndarray, period_mm: float, lit: np.ndarray) -> float | None:
    """Model-free target shift per pixel from the fundamental's phase across the longest run of
    columns ``lit`` (a column that sees no print has a phase of noise, and a gap could hide a turn)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], lit.astype(int), [0]])))
    if edges.size < 2:
        return None
    starts, stops = edges[::2], edges[1::2]
    longest = int(np.argmax(stops - starts))
    columns = slice(int(starts[longest]), int(stops[longest]))
    if stops[longest] - starts[longest] < 3:
        return None
    try:
        rate = phase_rate_mm(fundamental_phase(x_mm, line[:, columns], period_mm), period_mm)
    except (np.linalg.LinAlgError, ValueError):
        return None
    return rate if math.isfinite(rate) else None


def _ranges(index: np.ndarray) -> str:
    """``[0, 1, 2, 7]`` → ``"0-2, 7"``."""
    parts, start = [], int(index[0])
    for previous, current in zip(index[:-1], index[1:]):
        if current != previous + 1:
            parts.append(f"{start}-{int(previous)}" if previous != start else f"{start}")
            start = int(current)
    last = int(index[-1])
    parts.append(f"{start}-{last}" if last != start else f"{start}")
    return ", ".join(parts[:4]) + (", ..." if len(parts) > 4 else "")


def _positive(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) and number > 0 else None
