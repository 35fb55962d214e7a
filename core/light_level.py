"""The calibration's χ² level when its own light moved: the level tracking holds frames against.

A seed model (no per-frame light) calibrated while the camera's gain hunted keeps the light's
steps in its residual: its χ² level came out 57× the noise (paper rig, ±5 % in 1 % steps), while
the same frames with the light solved per frame, as the tracker solves it, sit at 1.01. Held
against 57×, a run's first frames with the light 5 % off (χ² 48–89) stayed under the single-frame
limit (98×): the light was not asked for, and they were placed 4–5 bounds off, unflagged; and no
change short of 60× the noise could ever show in the running χ².

So when the calibration frames with the light solved fit better than the fit's own level by more
than one frame's χ² needs to ask for the light (the tracker's single-frame limit), the misfit is
the light's, which tracking solves: the level is the light-solved one. Otherwise the fit's level
stands: two more unknowns lower a steady rig's χ² by ~2 % on a 100-pixel line, which held against
every steady run would eat a third of the running χ²'s margin.
"""

from __future__ import annotations

import math

ASK_SPREADS = 5.0  # one frame's χ² beyond this many of its standard deviations asks for the light (Tracker)


def ask_ratio(n_values: int) -> float:
    """One frame's χ² over the level beyond which the tracker solves the light: 5 standard
    deviations of a χ² per sample over ``n_values`` samples."""
    return 1.0 + ASK_SPREADS * math.sqrt(2.0 / max(n_values, 1))


def stated_level(fit_level: float, light_solved_level: float, n_values: int) -> float:
    """The χ² level a model states for tracking: ``light_solved_level`` (its calibration frames with
    the light solved per frame) where ``fit_level`` (the fit's own, the light as fitted) is beyond
    what one frame needs to ask for the light, else ``fit_level``."""
    if not (math.isfinite(light_solved_level) and light_solved_level > 0):
        return fit_level
    return light_solved_level if fit_level > ask_ratio(n_values) * light_solved_level else fit_level
