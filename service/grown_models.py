"""A model grown with one effect of the closed loop and fitted on a recording of that effect's physical
cause on the virtual rig (drivers/sim/causes.py): what tests and benchmarks evaluate every effect on.
It lives here because it joins the two layers: the rig records, core fits."""

from __future__ import annotations

from typing import Any

from graytrack.core import effects
from graytrack.core.calibration_data import calibration_data
from graytrack.core.structure import ModelSpec, fit_spec, fit_spec_pitch_search
from graytrack.drivers.sim.causes import EVERY_FORM
from graytrack.drivers.sim.scenarios import build_rig


def model_with(name: str, seed: int = 5, seconds: float | None = None,
               pitch_search: bool = False) -> tuple[Any, Any, Any]:
    """(a model grown with effect ``name`` (or a variant of one, ``effect:form``) and fitted on a
    recording of its cause, a second run of the same rig to track, the calibration recording). The
    structure is the effect's growth from the seed paper's; the fit is the calibration's own (two
    alternation rounds).

    ``pitch_search``: α·d searched as the closed loop searches it for an effect that needs it (a
    target map pins defects to x + α·d·u). Without, the map sits ~1 % off in α·d and its model
    misplaces its own run (7.9 µm against a 0.9 µm bound, stale on every frame): good enough for a
    test of how a model is evaluated, not for a figure of what a lab's model costs or measures."""
    cause = EVERY_FORM[name]
    seconds = seconds if seconds is not None else (4.0 if cause.scenario == "paper" else 2.0)
    calibration, _ = build_rig(cause.scenario, cause.effects, seed=seed).record(seconds)
    run, _ = build_rig(cause.scenario, cause.effects, seed=seed, run=1).record(seconds / 4)
    effect = effects.registry()[name.split(":")[0]]
    data = calibration_data(calibration)
    argument = cause.argument if cause.argument is not None else effect.screen(data)
    spec = effect.grow(ModelSpec(per_row=cause.per_row), argument)
    if spec is None or spec == ModelSpec(per_row=cause.per_row):
        raise ValueError(f"effect {name!r}: nothing to grow on its cause {cause.effects!r}")
    data = effects.prepare_data(spec, data)
    meta = calibration.meta
    if pitch_search and effect.search_pitch:
        return fit_spec_pitch_search(spec, data, meta["period_mm"], meta["pixel_pitch_mm"]).model, run, calibration
    return fit_spec(spec, data, meta["period_mm"], meta["pixel_pitch_mm"], rounds=2).model, run, calibration
