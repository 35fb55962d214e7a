"""For each effect the closed loop can add to a model, a physical cause of its family on the virtual
rig: what the tests and benchmarks record to get a model carrying that effect, without telling the
fit about it. A new effect in core/effects/ needs its cause here (tests/core/test_kernels.py checks).
Data only: the model grown on a cause is fitted in service/grown_models.py (fitting is core's, and a
driver imports no more of core than the recording format)."""

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
