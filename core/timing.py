"""Timing between the exposure and the grating readout.

The reference must describe the stage at the exposure's mid-point. A readout latched δ later
reads x(t + δ) ≈ x(t) + v·δ: at constant speed that is a constant offset that calibration absorbs,
but wherever the speed changes it is an error proportional to velocity that no gray-level model
can remove. Once δ is known the reference is moved back to the exposure instant.
"""

from __future__ import annotations

import numpy as np


def runs(t_s: np.ndarray) -> list[slice]:
    """Stretches of frames without a gap in time (held-out blocks, dropped frames)."""
    steps = np.diff(t_s)
    if steps.size == 0:
        return [slice(0, len(t_s))]
    typical = float(np.median(steps))
    breaks = np.flatnonzero(steps > 1.5 * typical) + 1
    edges = [0, *breaks.tolist(), len(t_s)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]


def velocity_mm_s(t_s: np.ndarray, x_mm: np.ndarray) -> np.ndarray:
    """Velocity at each frame from the reference, within runs (0 for a run of a single frame)."""
    velocity = np.zeros_like(x_mm)
    for run in runs(t_s):
        if run.stop - run.start >= 2:
            velocity[run] = np.gradient(x_mm[run], t_s[run])
    return velocity


def at_exposure(t_s: np.ndarray, reference_mm: np.ndarray, skew_s: float) -> np.ndarray:
    """The reference moved back by ``skew_s`` (readout latched that much after the exposure)."""
    if skew_s == 0.0:
        return reference_mm
    return reference_mm - skew_s * velocity_mm_s(t_s, reference_mm)


def model_reference(model, t_s: np.ndarray, reference_mm: np.ndarray) -> np.ndarray:
    """The grating at the exposure, as the ``model``'s calibration found it latched
    (``info["reference_skew_s"]``, the closed loop's ``reference_timing``).

    Everything that holds a model's positions against the grating must take this skew out, or it
    reads the latch as the model's error: at 66 mm/s a 0.3 ms latch is 20 µm, and a model that
    measures at its bound would be judged 36× off on its own calibration frames."""
    skew_s = float((getattr(model, "info", None) or {}).get("reference_skew_s", 0.0) or 0.0)
    return at_exposure(t_s, np.asarray(reference_mm, dtype=np.float64), skew_s)
