"""Named scenarios of the virtual rig, and the one entry point other code uses: :func:`build_rig`.

A scenario is a complete, physically plausible rig (target, light, camera, stage, grating, clock);
effects (effects.py) are then switched on by name on top of it. Scenarios that describe a real
imperfect rig (``lab``) are built from the same effects, so each imperfection exists in one place.

Frames: ``paper``, ``clean``, ``strip16`` and ``highspeed`` are float32 gray values (the paper's
Table 2 is a gray field plus Gaussian noise, not a digitiser output); ``lab`` is an 8-bit camera.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

from graytrack.drivers.sim import paper
from graytrack.drivers.sim.effects import EFFECTS, EffectError, EffectSpec, apply_effects
from graytrack.drivers.sim.optics import OpticsConfig
from graytrack.drivers.sim.rig import RigConfig, VirtualRig
from graytrack.drivers.sim.sensor import SensorConfig
from graytrack.drivers.sim.target import TargetConfig
from graytrack.drivers.sim.timing import TimingConfig


class ScenarioError(ValueError):
    """An unknown scenario name."""


@dataclass(frozen=True)
class Scenario:
    name: str
    summary: str
    build: Callable[[int], RigConfig]


SCENARIOS: dict[str, Scenario] = {}


def _scenario(name: str, summary: str):
    def register(fn: Callable[[int], RigConfig]) -> Callable[[int], RigConfig]:
        SCENARIOS[name] = Scenario(name, summary, fn)
        return fn

    return register


def _paper_config(name: str, n_rows: int = 1) -> RigConfig:
    return RigConfig(
        scenario=name,
        target=TargetConfig(kind="paper", period_mm=paper.PERIOD_MM),
        optics=OpticsConfig(pixel_pitch_mm=paper.PIXEL_PITCH_MM, n_pixels=paper.N_PIXELS, n_rows=n_rows),
        sensor=SensorConfig(bit_depth=None, read_noise_gray=paper.NOISE_GRAY),
        timing=TimingConfig(frame_rate_hz=50.0, exposure_s=0.001),
        stroke_mm=(0.0, paper.STROKE_MM),
        default_seconds=10.0,
    )


@_scenario("paper", "The seed paper's rig: Table 2 gray field, 100 px, α·d = 0.062 mm/px, σ = 0.7 gray, "
                    "1 row, 10.46 mm sweep in 10 s at 50 fps; float32 frames.")
def _paper(seed: int) -> RigConfig:
    return _paper_config("paper")


@_scenario("clean", "Ideal rig: a pure printed sine (A = 80, D = 128, τ = 8.62 mm) on the paper's geometry, "
                    "σ = 0.7 gray, float32 frames — the ideal model is exact.")
def _clean(seed: int) -> RigConfig:
    config = _paper_config("clean")
    config.target = TargetConfig(kind="sine", period_mm=paper.PERIOD_MM, amplitude_gray=80.0, offset_gray=128.0)
    return config


@_scenario("strip16", "The paper rig with a 16-row ROI strip (same per-pixel noise): √16 more information per frame "
                      "when the rows agree.")
def _strip16(seed: int) -> RigConfig:
    return _paper_config("strip16", n_rows=16)


LAB_EFFECTS = (
    "print_gamma:gamma=1.15", "harmonics:h2=0.01:h3=0.005", "gradient:per_10mm=0.04", "vignetting:edge=0.06",
    "flicker:mains_hz=50:depth=0.005", "tilt:deg=0.15", "distortion:k1=-0.004", "defocus:sigma_um=60",
    "prnu:sigma=0.008", "dsnu:sigma=0.4", "shot_noise:full_well=10000", "read_noise:gray=0.5", "quantize:bits=8",
    "dust:count=4:size_um=40:depth=0.15", "time_skew:ms=0.05", "jitter:us=20",
)


@_scenario("lab", "A realistic bench: printed sine with print gamma and slight harmonics, uneven light, vignetting, "
                  "50 Hz flicker, small tilt/distortion/defocus, PRNU/DSNU/shot/read noise, 8-bit, some dust, "
                  "50 µs latch skew, 16 rows × 128 px at 200 fps (built-in: " + ", ".join(LAB_EFFECTS) + ").")
def _lab(seed: int) -> RigConfig:
    config = RigConfig(
        scenario="lab",
        target=TargetConfig(kind="sine", period_mm=8.0, amplitude_gray=90.0, offset_gray=115.0, phase_rad=0.4),
        optics=OpticsConfig(pixel_pitch_mm=0.05, n_pixels=128, n_rows=16, sensor_width=640, sensor_height=480,
                            roi_x=256, roi_y=232, x_offset_mm=0.0),
        sensor=SensorConfig(bit_depth=8, read_noise_gray=0.5),
        timing=TimingConfig(frame_rate_hz=200.0, exposure_s=0.002),
        stroke_mm=(0.0, 20.0),
        default_seconds=10.0,
    )
    apply_effects(config, LAB_EFFECTS, seed, record=False)
    return config


@_scenario("highspeed", "The 16-row paper rig at 1,000 fps, 0.2 ms exposure, oscillating over the stroke at 2 Hz "
                        "(up to 66 mm/s): lock, motion blur and render-speed tests.")
def _highspeed(seed: int) -> RigConfig:
    config = _paper_config("highspeed", n_rows=16)
    config.timing = TimingConfig(frame_rate_hz=1000.0, exposure_s=0.0002)
    config.motion = "oscillation"
    config.motion_hz = 2.0
    config.default_seconds = 2.0
    return config


def list_scenarios() -> dict[str, str]:
    """Scenario name → one-line description."""
    return {name: sc.summary for name, sc in SCENARIOS.items()}


def list_effects() -> dict[str, str]:
    """Effect name → description with its parameters and defaults (``name:param=value`` syntax)."""
    return {name: eff.describe() for name, eff in EFFECTS.items()}


def build_config(scenario: str, effects: Sequence[EffectSpec] | str = (), seed: int = 0) -> RigConfig:
    """The scenario's configuration with ``effects`` applied (for callers who want to edit it further)."""
    if scenario not in SCENARIOS:
        raise ScenarioError(f"unknown scenario {scenario!r} (known: {', '.join(SCENARIOS)})")
    config = SCENARIOS[scenario].build(seed)
    apply_effects(config, effects, seed)
    return config


def build_rig(scenario: str, effects: Sequence[EffectSpec] | str = (), seed: int = 0, run: int = 0) -> VirtualRig:
    """A :class:`VirtualRig` for ``scenario`` with ``effects`` switched on, deterministic under ``seed``.

    ``effects`` are spec strings (``"tilt:deg=0.5"``, ``"flicker,prnu:sigma=0.02"``) or
    ``(name, {param: value})`` pairs. Raises :class:`ScenarioError` / :class:`EffectError`
    (both ``ValueError``) on unknown names or bad parameters. ``run`` > 0 is another session of the
    same rig: the same fixed patterns (PRNU, defects, dust) with noise of its own.
    """
    return VirtualRig(build_config(scenario, effects, seed), seed=seed, run=run)


__all__ = ["EffectError", "ScenarioError", "build_config", "build_rig", "list_effects", "list_scenarios"]
