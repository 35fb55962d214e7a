"""Per-pixel noise as a function of gray level: the photon-transfer model of EMVA 1288.

A camera's temporal noise is not one σ: read noise and the dark signal's own noise are constant,
photon shot noise grows with the signal, quantisation adds Δ²/12. In gray levels

    σ²(y) = σ²_read + K · max(y − y_dark, 0) + Δ²/12

with K the conversion gain in gray per electron (the slope of the photon-transfer curve). A fit
weighted by 1/σ²(y) and a Cramér–Rao bound computed with σ²(y) are what such data allow; one σ
for all gray levels over-trusts the bright pixels and under-trusts the dark ones.

This module holds the model and how it is written to a model file; estimating it from
calibration frames, and using it as weights, live with the fitting and tracking code.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from graytrack.core.errors import ModelError

_MIN_VARIANCE_GRAY2 = 1e-6  # keeps 1/σ² finite for a noiseless (simulated) sensor


@dataclass(frozen=True)
class PixelNoise:
    """σ²(y) = read_var + shot_gain · max(y − dark_gray, 0) + quant_var, in gray²."""

    read_var: float  # gray², signal-independent part (read noise, dark noise)
    shot_gain: float = 0.0  # K, gray per electron: the photon-transfer slope (0: no shot noise)
    dark_gray: float = 0.0  # gray level of no light
    quant_var: float = 0.0  # gray², Δ²/12 of the readout's quantisation

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not np.isfinite(value):
                raise ModelError(f"pixel noise: {name} must be finite, got {value}")
        if self.read_var < 0 or self.shot_gain < 0 or self.quant_var < 0:
            raise ModelError(f"pixel noise: variances and gain must not be negative ({self})")

    @classmethod
    def constant(cls, sigma_gray: float) -> "PixelNoise":
        """The single-σ model every recording supports."""
        return cls(read_var=float(sigma_gray) ** 2)

    @property
    def signal_dependent(self) -> bool:
        return self.shot_gain > 0.0

    def variance(self, gray: np.ndarray | float) -> np.ndarray:
        """σ² (gray²) of a sample whose expected value is ``gray``."""
        signal = np.maximum(np.asarray(gray, dtype=np.float64) - self.dark_gray, 0.0)
        return np.maximum(self.read_var + self.quant_var + self.shot_gain * signal, _MIN_VARIANCE_GRAY2)

    def sigma(self, gray: np.ndarray | float) -> np.ndarray:
        return np.sqrt(self.variance(gray))

    def as_dict(self) -> dict[str, float]:
        return {key: float(value) for key, value in asdict(self).items()}

    @classmethod
    def from_dict(cls, body: Any) -> "PixelNoise":
        if not isinstance(body, dict):
            raise ModelError(f"pixel noise must be an object, got {type(body).__name__}")
        unknown = set(body) - set(cls.__dataclass_fields__)
        if unknown:
            raise ModelError(f"pixel noise: unknown key {sorted(unknown)[0]!r}")
        try:
            return cls(**{key: float(value) for key, value in body.items()})
        except (TypeError, ValueError) as exc:
            raise ModelError(f"pixel noise is malformed ({exc})") from None
