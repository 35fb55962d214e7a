"""Errors raised by the core for input it refuses; the CLI and the daemon report them in one line."""


class GraytrackError(ValueError):
    """Base of every refusal the core makes on bad input or degenerate data."""


class ModelError(GraytrackError):
    """A model file or model parameters that cannot be used (wrong schema, wrong shape, nonsense)."""


class CalibrationError(GraytrackError):
    """Calibration data that cannot determine a model (no reference, too short a stroke, flat frames)."""


class TrackingError(GraytrackError):
    """Frames that do not fit the model they are tracked with (wrong pixel count, no acquisition)."""
