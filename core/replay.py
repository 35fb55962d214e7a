"""The calibration frames a model is judged on, weighed as the tracker weighs them, and replayed
through a lossy stream: shared by the judgements of core/adequacy.py and core/stream_focus.py.

A JPEG stream's error is not the sensor's noise and no calibration repeats it, so what it costs is
measured on the model's own images at the calibration's places, with the sensor's noise, through
the stream found in the frames (core/compression.py): images the model describes exactly, so that
what is left is the stream's.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from graytrack.core.calibration_data import CalibrationData
from graytrack.core.compression import round_trip
from graytrack.core.models.fourier import FourierModel

MAX_FRAMES = 400  # frames looked at (evenly spread): the figures are statistics, not a census
REPLAYS = 3  # noise draws of each frame looked at when a JPEG stream is replayed (a factor to ~2 %)


def picked_frames(data: CalibrationData) -> CalibrationData:
    """The calibration frames looked at: up to :data:`MAX_FRAMES`, evenly spread."""
    n_frames = data.frames.shape[0]
    return data.subset(np.unique(np.linspace(0, n_frames - 1, min(n_frames, MAX_FRAMES)).astype(int)))


def frame_weights(model: FourierModel, data: CalibrationData, values: np.ndarray) -> np.ndarray:
    """1/σ² per sample ``(K, P)`` of ``data``'s frames as the tracker weighs them: the noise model at
    the model's ``values`` (the variance of a row mean when rows are averaged), zero where a sample
    is not usable."""
    n_frames = data.frames.shape[0]
    weights = model.inverse_variance(values.reshape((n_frames,) + model.prepare(data.frames[:1]).shape[1:]))
    weights = weights.reshape(n_frames, -1) * model.rows_averaged(data.frames.shape[1])
    usable_samples = np.broadcast_to(data.weights, data.frames.shape)
    if model.n_rows == 1:  # a row mean is usable only where every row is (a glint's samples spoil it), as in the fit
        usable_samples = usable_samples.min(axis=1, keepdims=True)
    return weights * (model.prepare(usable_samples).reshape(n_frames, -1) > 0)


def replayed_frames(model: FourierModel, data: CalibrationData, table: np.ndarray,
                    seed: int = 0) -> Iterator[CalibrationData]:
    """:data:`REPLAYS` versions of ``data`` whose frames are the model's own images at their places,
    with the sensor's noise (seeded draws), through 8 bits and a JPEG stream's quantisation ``table``
    (compression.round_trip): the stream as the tracker meets it, on images the model describes."""
    values = np.broadcast_to(model.predict(data.x_mm), data.frames.shape)
    sigma = np.sqrt(model.noise().variance(values))
    rng = np.random.default_rng(seed)
    for _ in range(REPLAYS):
        noisy = np.clip(np.rint(values + rng.standard_normal(values.shape) * sigma), 0.0, 255.0)
        yield data.with_frames(round_trip(noisy, table))

