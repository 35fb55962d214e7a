"""One recursive estimator for every frame: the state of the rig (position, velocity, light, focus,
magnification, the camera's place), each nuisance drifting at a declared rate, updated by each
frame's gray values and, where it is read, the grating (docs/method.md, *The estimator*)."""

from graytrack.core.estimator.filter import GRATING_MODES, Estimator, FrameEstimate, as_result, calibration_level, track
from graytrack.core.estimator.settings import TUNABLES, EstimatorSettings, Tunable
from graytrack.core.estimator.state import STATE

__all__ = ["Estimator", "EstimatorSettings", "as_result", "calibration_level", "FrameEstimate", "GRATING_MODES",
           "STATE", "TUNABLES", "Tunable", "track"]
