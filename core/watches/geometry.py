"""The ``geometry`` watch: the model's own calibration refused the rig's geometry.

A model refused at calibration (a reversed pixel axis, a period the fit could not find) is kept
only to be studied (``calibrate(..., check=False)``); tracked with anyway, every one of its frames
is suspect, whatever its χ², which was that bad at calibration already (so the running χ² never
rises above the calibration's and the χ² monitor stays quiet). This watch blames ``geometry`` on
every frame of such a model.

What it does not do: tell a pixel axis reversed *after* calibration from one frame's χ². Tracked
with a reversed model, the paper rig's frames leave a median χ² of only 1.65 once the light field
is solved (it absorbs most of the mismatch) while the positions are 1.3 mm off: no χ² threshold
separates that from a light change. The grating does: ``track`` compares the frames with the model
at the reference positions, as given and reversed, before it tracks (geometry_check.orientation_mismatch).
"""

from __future__ import annotations

from graytrack.core.geometry_check import refusal
from graytrack.core.models.fourier import FourierModel
from graytrack.core.validity import FrameSign


class GeometryWatch:
    """Blames ``geometry`` on every frame of a model its calibration refused (reads no frame field).

    (core/watches/adequacy.py flags a model that errs beyond its bound on its own calibration frames,
    which such a model does too; this one says why, from the calibration's own verdict.)"""

    family = "geometry"
    decisive = True

    def __init__(self, model: FourierModel) -> None:
        self.reason = refusal(model)

    reads = ()

    def observe(self, sign: FrameSign) -> str | None:
        return self.step()

    def step(self) -> str | None:
        return self.family if self.reason is not None else None


def make(tracker) -> GeometryWatch | None:
    """The watch for ``tracker``'s model when its calibration refused its geometry (validity.monitor_for)."""
    watch = GeometryWatch(tracker.model)
    return watch if watch.reason is not None else None
