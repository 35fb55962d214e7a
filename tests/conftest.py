"""Shared fixtures: the seed paper's rig rendered from Table 2 (NOTES.md), seeded."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.core.calibration import calibrate
from graytrack.core.recording import Recording
from graytrack.drivers.sim import paper

PAPER_META = {"pixel_pitch_mm": paper.PIXEL_PITCH_MM, "period_mm": 8.6, "source": "tests: Table 2 field"}


def paper_recording(n_frames: int = 1000, n_rows: int = 1, seed: int = 1, shift_mm: float = 0.0,
                    meta: dict | None = None) -> Recording:
    """A sweep over the paper's 10.46 mm stroke with σ = 0.7 gray per pixel."""
    x_mm = np.linspace(0.0, paper.STROKE_MM, n_frames) + shift_mm
    frames = paper.paper_frames(x_mm, n_rows=n_rows, rng=np.random.default_rng(seed))
    frames = frames[:, 0, :] if n_rows == 1 else frames
    return Recording(frames.astype(np.float32), np.arange(n_frames) * 1e-3, x_mm,
                     dict(PAPER_META if meta is None else meta))


@pytest.fixture(scope="session")
def paper_cal() -> Recording:
    return paper_recording(seed=1)


@pytest.fixture(scope="session")
def paper_val() -> Recording:
    """Held-out frames: other noise, positions between the calibration's."""
    return paper_recording(seed=2, shift_mm=0.0047)


@pytest.fixture(scope="session")
def paper_models(paper_cal):
    return {kind: calibrate(paper_cal, kind) for kind in ("ideal", "paper")}
