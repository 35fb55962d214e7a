"""The model's own error at a place, in a mean over frames: what a stage at rest never averages.

A frame's stretch (core/stretch.py) is the projection of its residual onto the shape a magnification
leaves (its focus change, onto a blur's: core/watches/focus.py, the same argument). The residual holds
the frame's noise, which a mean over frames averages away, and the model's own error at that place
of the print, the same on every frame taken there. At a place the model was
not fitted to, its coefficients' noise leaves an error there (as the scale watch takes a position's:
``reference_place_sigma_um``, core/calibration_line.py): over a moving stage the places change and it
averages like noise; at rest it does not average at all. On the paper rig's daemon calibration (21
stops of 3 frames, 44 coefficients) the stretch at rest read −1400 to +1600 ppm from place to place
(±250 of noise), the positions within their bound of the truth, and the magnification watch, judging
the mean against its noise alone, flagged 42 % of the frames of a stage resting after calibration
(bench/daemon_rest.py). Its variance is a share of a frame's: :data:`COEFFICIENT_SHARE` × coefficients
/ calibration frames (measured: ``bench/daemon_rest.py --share``).

The frames' √weights are summed per place, decayed as the watch's mean is: the mean's share of the
places' own stretch has the variance share × Σ_place (Σ√w)² / (Σw)² (frames at one place: share × σ²;
spread over N places: that over N). A place is :data:`PLACE_MM` wide (the model's stretch changes
sign over 0.1-0.3 mm on the paper print); places :data:`PLACES` apart share a sum (a stage does not
rest on both within one memory). The focus watch keeps the same sum over its window
(:class:`WindowPlaces`).

A stage resting where the tracker solves a focus term (the model's misfit there asks for it) read
the model's own focus change there: 2.5 ± 0.6 px² at 3.33 mm on seed 2's calibration, flagged
``focus`` on 70 of a rest's 300 frames (0.73 % of the bench's rest frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from graytrack.core.watches import _kernels

PLACE_MM = 0.25
PLACES = 64
# Of the coefficients' noise, what the stretch at a place carries: measured at rest at 30 places of the paper
# rig, the model's stretch variance over a frame's was 0.09-0.19 of coefficients / frames (three seeds' 21 × 3
# stops, 44 coefficients), 0.07-0.26 with 10 frames a stop and ~0 with 30: it is the fit's noise, and shrinks as
# the calibration grows. Taken at 0.3, above every one measured (bench/daemon_rest.py --share).
COEFFICIENT_SHARE = 0.3


class PlaceSpread:
    """``add(x_mm, weight) -> variance`` (ppm²) for each frame the watch averages, in order."""

    def __init__(self, decay: float, share: float, place_mm: float = PLACE_MM) -> None:
        self.roots = np.zeros(PLACES)  # decayed Σ √w per place (1/ppm)
        self.total = np.zeros(1)  # decayed Σ w (1/ppm²)
        self.params = np.array([decay, place_mm, share])

    def add(self, x_mm: float, weight: float) -> float:
        return _kernels._place_add(self.roots, self.total, float(x_mm), float(weight), self.params)


@dataclass
class WindowPlaces:
    """Σ√w per place of the frames in a window (the focus watch's), kept as frames enter and leave:
    :meth:`concentration` is Σ_place (Σ√w)² / (Σw)², 1 when all sit at one place, 1/N over N places of
    equal weight; a frame of unknown place is a place apart."""

    _roots: dict[int, list[float]] = field(default_factory=dict)  # place → [Σ√w, frames]
    _alone: float = 0.0  # Σw of frames of unknown place

    def add(self, x_mm: float, weight: float, sign: float = 1.0) -> None:
        if not math.isfinite(x_mm):
            self._alone += sign * weight
            return
        place = math.floor(x_mm / PLACE_MM)
        entry = self._roots.setdefault(place, [0.0, 0.0])
        entry[0] += sign * math.sqrt(weight)
        entry[1] += sign
        if entry[1] <= 0.0:
            del self._roots[place]

    def remove(self, x_mm: float, weight: float) -> None:
        self.add(x_mm, weight, -1.0)

    def clear(self) -> None:
        self._roots.clear()
        self._alone = 0.0

    def concentration(self, total_weight: float) -> float:
        if not total_weight > 0.0:
            return 0.0
        return (sum(root * root for root, _ in self._roots.values()) + self._alone) / (total_weight * total_weight)


def model_share(model) -> float:
    """The share of a frame's stretch variance that is the model's own at a place it was not fitted
    to: :data:`COEFFICIENT_SHARE` × its coefficients over its calibration's frames (0 when either is
    not known: an older model)."""
    frames = int((getattr(model, "info", None) or {}).get("calibration_frames") or 0)
    coefficients = int(getattr(model, "n_coeffs", 0) or 0)
    return min(COEFFICIENT_SHARE * coefficients / frames, 1.0) if frames > 0 else 0.0
