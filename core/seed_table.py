"""The seed paper's Tables 1–2 and Fig. 5, computed the way the paper computed them.

The paper (NOTES.md) fits each model by least squares on a calibration sweep over the stroke and
states its RMSE over every sample of that fit; it then measures a sweep over the whole stroke with
the sequential solution started from the grating's first reading (x0 = 0 there), each frame from
the one before, the model as calibrated: no per-frame light, no reweighting of pixels (eq. 13 has
neither). Its error figures are the mean and standard deviation of (measured − grating) over every
frame of that sweep: 56.4 µm for the ideal sine, 1.5 µm for its corrected model.

The library's tracker has grown nuisances since (the light solved when the residual asks for it,
pixels set aside): right for a rig, wrong for reproducing a table, because each of them changes
what the ideal sine, a model 12× off in gray, reports. The comparison therefore names its
protocol here, once, and ``graytrack demo`` and the tests read the table from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from graytrack.core.calibration import calibrate
from graytrack.core.recording import Recording
from graytrack.core.tracking import track

# The seed paper's figures (Tables 1–2, Fig. 5): RMSE in gray, error mean and std in µm.
PAPER = {"ideal": {"rmse_gray": 7.8248, "period_mm": 8.667, "error_mean_um": -1.1, "error_std_um": 56.4},
         "paper": {"rmse_gray": 0.7130, "period_mm": 8.62, "error_mean_um": 0.49, "error_std_um": 1.5}}


@dataclass(frozen=True)
class TableRow:
    """One model's line of the table."""

    kind: str
    rmse_gray: float  # calibration residual over every sample of the fit
    period_mm: float
    error_mean_um: float  # measured − grating, over every placed frame
    error_std_um: float  # population standard deviation of the same
    bound_um: float  # rms of the frames' Cramér–Rao bounds: what noise alone allows
    placed: int  # frames the sequential solution placed, of ``frames``
    frames: int

    def as_dict(self) -> dict:
        """For a report: the row's figures and, under ``paper``, the paper's own for the same model; a
        figure that does not exist (no frame placed) is None, as every report's (never NaN)."""
        row = {key: None if isinstance(value := getattr(self, key), float) and not np.isfinite(value) else value
               for key in self.__dataclass_fields__}
        return {**row, "paper": dict(PAPER.get(self.kind, {}))}

    def line(self) -> str:
        """As ``graytrack demo`` prints it, with the paper's own figures beside."""
        paper = PAPER.get(self.kind, {})
        quoted = (f" | paper: rmse {paper['rmse_gray']:.3f}, error {paper['error_mean_um']:+.2f} ± "
                  f"{paper['error_std_um']:.1f} um" if paper else "")
        lost = f", {self.frames - self.placed} frame(s) not placed" if self.placed < self.frames else ""
        return (f"{self.kind:<6} rmse {self.rmse_gray:7.3f} gray, tau {self.period_mm:.4f} mm | error "
                f"{self.error_mean_um:+7.2f} ± {self.error_std_um:7.3f} um (bound {self.bound_um:.3f} um)"
                f"{lost}{quoted}")


def seed_table(calibration: Recording, measured: Recording,
               kinds: tuple[str, ...] = ("ideal", "paper")) -> list[TableRow]:
    """Fit each model kind on ``calibration``; measure ``measured`` (a sweep over the stroke with its
    grating reading) the paper's way: sequential from the first reading (the grating is not read
    again until the comparison), the calibrated light, every pixel."""
    if not np.isfinite(measured.reference[0]):
        raise ValueError("the measured sweep needs a grating reading on its first frame (the paper's x0)")
    rows = []
    for kind in kinds:
        result = calibrate(calibration, kind)
        # the grating gives x0 and the comparison, nothing in between: no re-anchoring on it
        tracked = track(result.model, measured.frames, x0_mm=float(measured.reference[0]), light="fixed", robust=False)
        error = tracked.error_um(measured.reference)
        placed = np.isfinite(error)
        bound = tracked.crlb_mm[np.isfinite(tracked.crlb_mm)] * 1e3
        rows.append(TableRow(kind, float(result.rmse_gray), float(result.model.period_mm),
                             float(np.mean(error[placed])) if placed.any() else float("nan"),
                             float(np.std(error[placed])) if placed.any() else float("nan"),
                             float(np.sqrt(np.mean(bound**2))) if bound.size else float("nan"),
                             int(placed.sum()), int(error.size)))
    return rows
