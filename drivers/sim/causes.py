"""For each effect the closed loop can add to a model, a physical cause of its family on the virtual
rig: what the tests and benchmarks record to get a model carrying that effect, without telling the
fit about it. A new effect in core/effects/ needs its cause here (tests/core/test_kernels.py checks)."""

from __future__ import annotations

from typing import Any, NamedTuple


class Cause(NamedTuple):
    scenario: str  # drivers/sim/scenarios.py
    effects: str  # the rig's effects (drivers/sim/effects.py spec)
    argument: Any = None  # what the closed loop's probe hands to the effect's grow (None: its screen of the data)
    per_row: bool = False  # the effect grown on a per-row model (rows fitted apart)


EFFECT_CAUSES: dict[str, Cause] = {
    "bad_pixels": Cause("paper", "bad_pixels:stuck=1:dead=1:hot=1"),
    "clipping": Cause("paper", "saturation:gain=1.3,quantize:bits=8", (0.0, 255.0)),
    "common_mode": Cause("paper", "flicker:mains_hz=50:depth=0.05"),
    "flat_field": Cause("paper", "prnu:sigma=0.03,dsnu:sigma=2"),
    "focus": Cause("paper", "defocus:sigma_um=200"),
    "harmonics": Cause("paper", "print_gamma:gamma=1.4,harmonics:h2=0.05:h3=0.02"),
    "pixel_polynomial": Cause("paper", "distortion:k1=0.02,vignetting:edge=0.15"),
    "reference_timing": Cause("paper", "grating_latency:ms=2", 0.002),
    "rows": Cause("strip16", "tilt:deg=2"),
    "stroke": Cause("paper", "pitch_scale:ppm=500,gradient:per_10mm=0.08"),
    "target_map": Cause("paper", "dust:count=6,scratches:count=3"),
}
# Further forms of an effect than its first growth, named effect:form: tested as the effects are.
EFFECT_VARIANTS: dict[str, Cause] = {
    "target_map:rows": Cause("strip16", "dust:count=8:size_um=60", per_row=True),  # a map a row
}
EVERY_FORM: dict[str, Cause] = {**EFFECT_CAUSES, **EFFECT_VARIANTS}  # what tests and benchmarks run through


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
    from graytrack.core import effects
    from graytrack.core.calibration_data import calibration_data
    from graytrack.core.structure import ModelSpec, fit_spec, fit_spec_pitch_search
    from graytrack.drivers.sim.scenarios import build_rig

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
