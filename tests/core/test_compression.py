"""Frames of an MJPEG stream are recognised, with their quality, and the bound they still allow."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.compression import bound_with_quantisation_mm, find_jpeg, quantisation_table
from graytrack.drivers.sim.scenarios import build_rig


@pytest.mark.parametrize("quality", [50, 75])
def test_a_jpeg_stream_is_found_with_its_quality(quality):
    frames, _ = build_rig("lab", f"mjpeg:quality={quality}", seed=3).record(0.5)
    found = find_jpeg(frames.frames)
    assert found is not None and abs(found.quality - quality) <= 2 and found.score > 0.7


@pytest.mark.parametrize("scenario, effects", [("lab", ""), ("strip16", "quantize:bits=8")])
def test_raw_frames_are_not_taken_for_jpeg(scenario, effects):
    frames, _ = build_rig(scenario, effects, seed=3).record(0.5)
    assert find_jpeg(frames.frames) is None


def test_the_bound_with_quantisation_is_the_white_one_without_it_and_larger_with_it():
    rng = np.random.default_rng(1)
    slope = rng.normal(0.0, 50.0, (4, 16, 128))  # gray per mm, whole 8×8 blocks
    sigma2 = 0.8
    white = 1.0 / np.sqrt((slope**2).sum(axis=(1, 2)) / sigma2)
    np.testing.assert_allclose(bound_with_quantisation_mm(slope, sigma2, np.full((8, 8), 1e-6)), white, rtol=1e-9)
    with_q75 = bound_with_quantisation_mm(slope, sigma2, quantisation_table(75))
    assert np.all(with_q75 > 2.0 * white)  # white slopes: most of their energy sits where q75 steps are coarse
