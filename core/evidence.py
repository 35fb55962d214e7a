"""Structure in the residual, scored against what noise alone would produce: the evidence type
and what the effects' probes (core/effects/) share.

Each effect's probe regresses the residual on a small basis its family of physical causes would
leave. Probes whose parameters carry over between frames are fitted on the training residual and
scored on the held-out residual (cross-validation); per-frame probes are scored against the sum
of squares that fitting their parameters to pure noise would remove. Scores are z-values in
units of that noise, so they compare across probes of different size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from graytrack.core.basis import legendre_basis, scaled
from graytrack.core.regression import tall_least_squares

if TYPE_CHECKING:  # a leaf module: effects and the loop import it, it imports neither
    from graytrack.core.diagnosis.heldout import Fit, LoopModel


@dataclass
class Evidence:
    effect: str  # key into the effect library
    axis: str
    explained_gray2: float  # held-out sum of squares the structure removes
    z: float  # how many noise standard deviations that is beyond chance
    share: float  # fraction (0…1) of the held-out residual's excess over noise it explains
    text: str
    argument: Any = None  # what the effect's grow() needs from the probe (clip limits, a skew, pixels)

    def as_dict(self) -> dict[str, float | str]:
        return {"effect": self.effect, "axis": self.axis, "z": round(float(self.z), 2),
                "share": round(float(self.share), 4),
                "text": self.text}


def _flat(values: np.ndarray) -> np.ndarray:
    return values.reshape(-1)


def _cross_validated(train_basis: np.ndarray, train_res: np.ndarray, val_basis: np.ndarray,
                     val_res: np.ndarray) -> float:
    """Held-out sum of squares removed by a basis fitted on the training residual."""
    coef = tall_least_squares(train_basis, train_res)
    return float(val_res @ val_res - (val_res - val_basis @ coef) @ (val_res - val_basis @ coef))


def stroke_poly(fit: Fit, degree: int = 4) -> np.ndarray:
    lo, hi = fit.model.stroke_range_mm
    return legendre_basis(scaled(fit.data.x_mm, lo, hi), degree)[:, 1:]  # (K, degree)


Basis = Callable[["Fit"], np.ndarray]  # -> (K, Rm, n, p) in the model's row layout


def trig_times_pixel(trig: np.ndarray, pixel: np.ndarray) -> np.ndarray:
    """Every trig term ``(K, Rm, n, A)`` times every pixel function ``(n, P)``: a basis ``(K, Rm, n, A·P)``."""
    out = trig[..., :, None] * pixel[None, None, :, None, :]
    return out.reshape(out.shape[:3] + (-1,))


def excess_over_noise(train: Fit, val: Fit) -> float:
    sigma2 = val.data.sigma_gray**2
    return max(float((val.residual**2).sum()) - sigma2 * float(val.usable.sum()), sigma2)


def share_above_noise(beyond_noise_gray2: float, train: Fit, val: Fit) -> float:
    """The fraction, in [0, 1], of the held-out residual above noise that a structure accounts for.

    ``beyond_noise_gray2`` is what the structure removes from the held-out sum of squares beyond
    what fitting it to noise alone would remove (cross-validated probes: all they remove; probes
    fitted on the held-out frames: less their parameters' share of σ²). The residual above noise,
    estimated as its sum of squares less σ² per sample, can come out smaller than that when the
    residual is at the noise level (the model-free σ a little high): what a structure removes
    beyond noise is by definition part of the residual above noise, so the share is taken of the
    larger of the two and 100 % reads "all the residual that the noise does not account for".
    A structure that removes no more than noise would counts for nothing: 0.
    """
    beyond = float(beyond_noise_gray2)
    if not np.isfinite(beyond) or beyond <= 0.0:
        return 0.0
    return beyond / max(excess_over_noise(train, val), beyond)


def explains(share: float) -> str:
    """The words every probe ends its evidence with."""
    return f"explain {100 * share:.0f}% of the held-out residual above noise"


def z_beyond_noise(explained: float, n_params: float, sigma2: float) -> float:
    """Removed sum of squares beyond what n_params fitted to noise remove, in noise std units."""
    return (explained / sigma2 - n_params) / np.sqrt(2.0 * max(n_params, 1.0))


def model_rows(fit: Fit) -> tuple[np.ndarray, np.ndarray, int]:
    """Residual and usable mask in the model's row layout; rows a shared model averages are averaged.

    Structure common to all rows survives the average while the work drops R-fold; the returned
    factor turns sums of squares of the mean back into sums over the rows.
    """
    if fit.model.n_rows == fit.data.frames.shape[1]:
        return fit.residual, fit.usable, 1
    n_rows = fit.data.frames.shape[1]
    return fit.residual.mean(axis=1, keepdims=True), fit.usable.min(axis=1, keepdims=True), n_rows


def cross_validated_evidence(effect: str, axis: str, stage: LoopModel, basis: Basis, label: str) -> Evidence:
    """Evidence for a structure whose coefficients carry over between frames: ``basis`` fitted to
    the training residual, scored by what it removes from the held-out residual."""
    train, val = stage.train, stage.val
    sigma2 = val.data.sigma_gray**2
    (res_t, use_t, _), (res_v, use_v, factor) = model_rows(train), model_rows(val)
    b_train, b_val = basis(train), basis(val)
    p = b_train.shape[-1]
    mask_t, mask_v = use_t.reshape(-1) > 0, use_v.reshape(-1) > 0
    explained = factor * _cross_validated(b_train.reshape(-1, p)[mask_t], _flat(res_t)[mask_t],
                                          b_val.reshape(-1, p)[mask_v], _flat(res_v)[mask_v])
    # Cross-validated: noise alone removes about nothing on held-out data, so no parameter count.
    z = explained / sigma2 / np.sqrt(2.0 * p)
    share = share_above_noise(explained, train, val)
    return Evidence(effect, axis, explained, z, share, f"{label} {explains(share)}")
