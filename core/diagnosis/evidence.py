"""Structure in the residual, axis by axis, scored against what noise alone would produce.

Each probe regresses the residual on a small basis that one family of physical effects would
leave: harmonics of the target phase beyond the model's order, smooth pixel dependence beyond its
degree, a rough per-pixel gain and offset (flat field), gain/offset/phase drifting along the
stroke, a gain and offset per frame, row-to-row shifts (tilt), and samples stuck at the sensor's
limits. Probes whose parameters carry over between frames are fitted on the training residual and
scored on the held-out residual (cross-validation); per-frame probes are scored against the sum
of squares that fitting their parameters to pure noise would remove. Scores are z-values in
units of that noise, so they compare across probes of different size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from graytrack.core.basis import legendre_basis, scaled, trig_basis
from graytrack.core.structure import DEFAULT_MAP_STEPS, MAX_MAP_STEPS, fit_target_map
from graytrack.core.diagnosis.heldout import Fit
from graytrack.core.regression import weighted_affine
from graytrack.core.timing import velocity_mm_s


@dataclass
class Evidence:
    effect: str  # key into the effect library
    axis: str
    explained_gray2: float  # held-out sum of squares the structure removes
    z: float  # how many noise standard deviations that is beyond chance
    share: float  # fraction of the held-out residual's excess over noise it explains
    text: str

    def as_dict(self) -> dict[str, float | str]:
        return {"effect": self.effect, "axis": self.axis, "z": round(float(self.z), 2), "share": round(float(self.share), 4),
                "text": self.text}


def _flat(values: np.ndarray) -> np.ndarray:
    return values.reshape(-1)


def _cross_validated(train_basis: np.ndarray, train_res: np.ndarray, val_basis: np.ndarray,
                     val_res: np.ndarray) -> float:
    """Held-out sum of squares removed by a basis fitted on the training residual."""
    coef, *_ = np.linalg.lstsq(train_basis, train_res, rcond=None)
    return float(val_res @ val_res - (val_res - val_basis @ coef) @ (val_res - val_basis @ coef))


def _stroke_poly(fit: Fit, degree: int = 4) -> np.ndarray:
    lo, hi = fit.model.stroke_range_mm
    return legendre_basis(scaled(fit.data.x_mm, lo, hi), degree)[:, 1:]  # (K, degree)


Basis = Callable[[Fit], np.ndarray]  # -> (K, Rm, n, p) in the model's row layout


def harmonic_basis(fit: Fit) -> np.ndarray:
    model = fit.model
    extra = 4
    trig = trig_basis(model.phase(fit.data.x_mm), model.harmonics + extra)[..., 2 * model.harmonics + 1:]
    pixel = model.pixel_basis()[:, :2]
    out = trig[..., :, None] * pixel[None, None, :, None, :]
    return out.reshape(out.shape[:3] + (-1,))


def pixel_polynomial_basis(fit: Fit) -> np.ndarray:
    model = fit.model
    trig = trig_basis(model.phase(fit.data.x_mm), model.harmonics)
    u = np.arange(model.n_pixels, dtype=np.float64)
    higher = legendre_basis(scaled(u, 0, model.n_pixels - 1), model.pixel_degree + 3)[:, model.pixel_degree + 1:]
    out = trig[..., :, None] * higher[None, None, :, None, :]
    return out.reshape(out.shape[:3] + (-1,))


def stroke_basis(fit: Fit) -> np.ndarray:
    """Gain, offset and phase drifting along the stroke: [F, 1, F′] × P_j(x), j = 1..4."""
    poly = _stroke_poly(fit)[:, None, None, :]
    parts = [fit.smooth[..., None] * poly, np.ones_like(fit.smooth)[..., None] * poly, fit.slope[..., None] * poly]
    return np.concatenate(parts, axis=-1)


CROSS_VALIDATED: dict[str, tuple[str, Basis, str]] = {
    "harmonics": ("target phase", harmonic_basis, "harmonics {lo}–{hi} of the target phase"),
    "pixel_polynomial": ("pixel index (smooth)", pixel_polynomial_basis, "pixel dependence beyond degree {deg}"),
    "stroke": ("stroke position", stroke_basis, "gain, offset or phase drifting along the stroke"),
}


def _excess(train: Fit, val: Fit) -> float:
    sigma2 = val.data.sigma_gray**2
    return max(float((val.residual**2).sum()) - sigma2 * float(val.usable.sum()), sigma2)


def _z(explained: float, n_params: float, sigma2: float) -> float:
    """Removed sum of squares beyond what n_params fitted to noise remove, in noise std units."""
    return (explained / sigma2 - n_params) / np.sqrt(2.0 * max(n_params, 1.0))


def _model_rows(fit: Fit) -> tuple[np.ndarray, np.ndarray, int]:
    """Residual and usable mask in the model's row layout; rows a shared model averages are averaged.

    Structure common to all rows survives the average while the work drops R-fold; the returned
    factor turns sums of squares of the mean back into sums over the rows.
    """
    if fit.model.n_rows == fit.data.frames.shape[1]:
        return fit.residual, fit.usable, 1
    n_rows = fit.data.frames.shape[1]
    return fit.residual.mean(axis=1, keepdims=True), fit.usable.min(axis=1, keepdims=True), n_rows


def cross_validated_evidence(train: Fit, val: Fit) -> list[Evidence]:
    sigma2 = val.data.sigma_gray**2
    excess = _excess(train, val)
    (res_t, use_t, _), (res_v, use_v, factor) = _model_rows(train), _model_rows(val)
    out = []
    for effect, (axis, basis, template) in CROSS_VALIDATED.items():
        b_train, b_val = basis(train), basis(val)
        p = b_train.shape[-1]
        mask_t, mask_v = use_t.reshape(-1) > 0, use_v.reshape(-1) > 0
        explained = factor * _cross_validated(b_train.reshape(-1, p)[mask_t], _flat(res_t)[mask_t],
                                              b_val.reshape(-1, p)[mask_v], _flat(res_v)[mask_v])
        # Cross-validated: noise alone removes about nothing on held-out data, so no parameter count.
        z = explained / sigma2 / np.sqrt(2.0 * p)
        text = template.format(lo=train.model.harmonics + 1, hi=train.model.harmonics + 4, deg=train.model.pixel_degree)
        out.append(Evidence(effect, axis, explained, z, explained / excess,
                            f"{text} explain {100 * explained / excess:.0f}% of the held-out residual above noise"))
    return out


def flat_field_evidence(train: Fit, val: Fit) -> Evidence:
    """A gain and offset per pixel, fitted on training frames, applied to held-out ones."""
    slope, intercept = weighted_affine(train.residual, train.predicted, train.usable, axis=(0,))
    r_v = val.residual
    corrected = r_v - (slope * val.predicted + intercept) * val.usable
    explained = float((r_v**2).sum() - (corrected**2).sum())
    sigma2 = val.data.sigma_gray**2
    p = 2 * slope.size
    z = explained / sigma2 / np.sqrt(2.0 * p)
    spread = float(np.std(slope)) * 100
    excess = _excess(train, val)
    return Evidence("flat_field", "pixel index (pixel to pixel)", explained, z, explained / excess,
                    f"a gain ({spread:.2f}% rms) and offset per pixel explain {100 * explained / excess:.0f}% "
                    "of the held-out residual above noise")


def common_mode_evidence(train: Fit, val: Fit) -> Evidence:
    """A gain and offset per frame (fitted on the held-out frames themselves, charged per parameter)."""
    if train.model.common_mode:
        return Evidence("common_mode", "time (per frame)", 0.0, 0.0, 0.0, "already modelled")
    r = val.residual
    gain, offset = weighted_affine(r, val.predicted, val.usable, axis=(1, 2))
    corrected = (r - (gain[:, None, None] * val.predicted + offset[:, None, None])) * val.usable
    explained = float((r**2).sum() - (corrected**2).sum())
    sigma2 = val.data.sigma_gray**2
    p = 2 * len(gain)
    z = _z(explained, p, sigma2)
    excess = _excess(train, val)
    # Smooth-in-stroke gain belongs to the stroke probe; only what varies from frame to frame counts here.
    order = np.argsort(val.data.x_mm)
    jitter = np.diff(gain[order])
    frame_to_frame = float(np.std(jitter) / np.sqrt(2)) * 100
    return Evidence("common_mode", "time (per frame)", explained, z, explained / excess,
                    f"a gain per frame ({frame_to_frame:.2f}% rms from frame to frame) and offset explain "
                    f"{100 * explained / excess:.0f}% of the held-out residual above noise")


def row_evidence(train: Fit, val: Fit) -> Evidence | None:
    """Rows that disagree: a shift (tilt), gain and offset per row, fitted on training frames.

    The basis is block-diagonal in the row, so each row's three coefficients are solved on
    their own: a batch of 3×3 systems instead of one large least-squares problem.
    """
    if val.data.frames.shape[1] < 2 or train.model.n_rows > 1:
        return None

    def design(fit: Fit) -> np.ndarray:
        shape = fit.data.frames.shape
        parts = (np.broadcast_to(fit.slope, shape), np.broadcast_to(fit.smooth, shape), np.ones(shape))
        return np.stack(parts, axis=-1) * fit.usable[..., None]

    d_t, d_v = design(train), design(val)
    gram = np.einsum("krup,kruq->rpq", d_t, d_t)
    coef = np.linalg.solve(gram + 1e-9 * np.eye(3), np.einsum("krup,kru->rp", d_t, train.residual)[..., None])[..., 0]
    corrected = val.residual - np.einsum("krup,rp->kru", d_v, coef)
    explained = float((val.residual**2).sum() - (corrected**2).sum())
    sigma2 = val.data.sigma_gray**2
    n_rows = val.data.frames.shape[1]
    per_row_um = float(np.polyfit(np.arange(n_rows), coef[:, 0] * 1e3, 1)[0])
    excess = _excess(train, val)
    return Evidence("rows", "row (tilt)", explained, explained / sigma2 / np.sqrt(6.0 * n_rows), explained / excess,
                    f"rows see the target shifted by {per_row_um:+.2f} µm per row (tilt); per-row terms explain "
                    f"{100 * explained / excess:.0f}% of the held-out residual above noise")


def target_map_evidence(train: Fit, val: Fit) -> Evidence | None:
    """Local defects fixed to the target (dust, scratches): a fine map along the target coordinate,
    learnt from training frames, predicts the held-out residual wherever the same spot is seen."""
    model = train.model
    steps = DEFAULT_MAP_STEPS
    if model.target_map is not None:  # a map exists: would one twice as fine say more?
        steps = 2 * int(round(model.pixel_pitch_mm / model.target_map_step_mm))
        if steps > MAX_MAP_STEPS:
            return None
    (res_t, use_t, _), (res_v, use_v, factor) = _model_rows(train), _model_rows(val)
    found = fit_target_map(model.with_changes(coeffs=model.coeffs, target_map=None), train.data.x_mm,
                           train.smooth + res_t, train.smooth, use_t, steps)
    mapped = model.with_changes(coeffs=model.coeffs, **found)
    predicted = val.smooth * (mapped.target_factor(val.data.x_mm)[0] - 1.0) * use_v
    explained = factor * float((res_v**2).sum() - ((res_v - predicted) ** 2).sum())
    sigma2 = val.data.sigma_gray**2
    excess = _excess(train, val)
    deepest = float(np.abs(found["target_map"]).max()) * 100
    return Evidence("target_map", "target coordinate (local)", explained,
                    explained / sigma2 / np.sqrt(2.0 * found["target_map"].size), explained / excess,
                    f"spots fixed to the target (deepest {deepest:.1f}% of the light, on a "
                    f"{found['target_map_step_mm'] * 1e3:.0f} µm grid) explain "
                    f"{100 * explained / excess:.0f}% of the held-out residual above noise")


def timing_evidence(val: Fit, error_um: np.ndarray) -> tuple[Evidence, float] | None:
    """Tracking error proportional to velocity: the grating is read at another instant than the
    exposure's mid-point. Returns the evidence and the skew δ (s) that −v·δ fits."""
    velocity = velocity_mm_s(val.data.t_s, val.data.x_mm)
    usable = np.isfinite(error_um)
    v, e = velocity[usable], error_um[usable]
    if v.size < 10:
        return None
    spread = float(((v - v.mean()) ** 2).sum())
    if spread <= 1e-12:
        return None
    slope = float(((v - v.mean()) * (e - e.mean())).sum() / spread)  # µm per (mm/s)
    fitted = e.mean() + slope * (v - v.mean())
    remaining = float(((e - fitted) ** 2).sum())
    total = float(((e - e.mean()) ** 2).sum())
    z = abs(slope) / np.sqrt(remaining / (v.size - 2) / spread) if remaining > 0 else np.inf
    share = 1.0 - remaining / total if total > 0 else 0.0
    skew_s = -slope * 1e-3  # e = −v·δ with e in µm, v in mm/s
    text = (f"the tracking error follows velocity: the grating reads {skew_s * 1e3:+.3f} ms from mid-exposure "
            f"(−v·δ explains {100 * share:.0f}% of the error variance)")
    return Evidence("reference_timing", "velocity", share, float(z), share, text), skew_s


def clipping_evidence(train: Fit, val: Fit) -> tuple[Evidence, tuple[float, float]] | None:
    """Samples piled up at the top or bottom of the gray range: a clipped sensor."""
    if train.model.clip_gray is not None:
        return None
    frames = train.data.frames
    top, bottom = float(frames.max()), float(frames.min())
    at_top, at_bottom = float((frames >= top).mean()), float((frames <= bottom).mean())
    threshold = 0.002  # a continuous signal plus noise almost never repeats its extreme value
    if max(at_top, at_bottom) < threshold:
        return None
    lo = bottom if at_bottom >= threshold else -np.inf
    hi = top if at_top >= threshold else np.inf
    share = max(at_top, at_bottom)
    evidence = Evidence("clipping", "gray level", 0.0, 1e3 * share, share,
                        f"{100 * at_top:.1f}% of samples sit at the ceiling {top:g} and {100 * at_bottom:.1f}% at the "
                        f"floor {bottom:g}: the sensor clips there")
    return evidence, (float(lo), float(hi))


def all_evidence(train: Fit, val: Fit) -> list[Evidence]:
    """Every probe's verdict, strongest first."""
    found = cross_validated_evidence(train, val) + [flat_field_evidence(train, val), common_mode_evidence(train, val)]
    for probe in (row_evidence, target_map_evidence):
        evidence = probe(train, val)
        if evidence is not None:
            found.append(evidence)
    return sorted(found, key=lambda ev: ev.explained_gray2, reverse=True)
