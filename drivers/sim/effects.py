"""Effects: named, parameterised physical imperfections that edit a :class:`RigConfig`.

An effect is a small function registered under a name with documented parameters and defaults.
Switching effects on by name (``--effects tilt:deg=0.5,flicker``) is how scenarios get their
imperfections and how the closed loop is tested against *undeclared* effects of arbitrary
magnitude and in any combination: every effect accepts any magnitude its parameters allow, and
effects compose (they edit different parts of the configuration, or add up where they share one).

Spec syntax (``parse_effects``)::

    name                      defaults
    name:key=value:key=value  parameters
    a,b:key=value             several effects, comma-separated
    flicker:mains_hz=60,depth=0.05   a bare key=value after a comma continues the previous effect

Effects that need randomness (dust positions, flicker phase…) draw it from a stream of their own,
derived from the rig's seed and the effect's name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Mapping, Sequence

import numpy as np

from graytrack.drivers.sim.camera_side import VeilConfig, WindowSpeck
from graytrack.drivers.sim.optics import pixel_geometry
from graytrack.drivers.sim.sensor import FULL_SCALE_GRAY, BadPixel
from graytrack.drivers.sim.shadow import ShadowConfig
from graytrack.drivers.sim.target import Defect, Growth

if TYPE_CHECKING:
    from graytrack.drivers.sim.rig import RigConfig


class EffectError(ValueError):
    """An unknown effect or a bad parameter in an effect spec."""


@dataclass(frozen=True)
class Param:
    name: str
    default: float
    doc: str


Apply = Callable[["RigConfig", dict[str, float], np.random.Generator], None]


@dataclass(frozen=True)
class RigEffect:
    name: str
    group: str
    summary: str
    params: tuple[Param, ...]
    apply: Apply

    def describe(self) -> str:
        """One line: what it does and its parameters with defaults."""
        if not self.params:
            return f"[{self.group}] {self.summary}"
        plist = ", ".join(f"{p.name}={p.default:g} ({p.doc})" for p in self.params)
        return f"[{self.group}] {self.summary} Parameters: {plist}."

    def resolve(self, given: Mapping[str, float]) -> dict[str, float]:
        known = {p.name: p.default for p in self.params}
        unknown = sorted(set(given) - set(known))
        if unknown:
            names = ", ".join(known) or "none"
            raise EffectError(f"effect {self.name!r} has no parameter {unknown[0]!r} (parameters: {names})")
        values = dict(known)
        for key, value in given.items():
            try:
                values[key] = float(value)
            except (TypeError, ValueError):
                raise EffectError(f"effect {self.name!r}: parameter {key}={value!r} is not a number") from None
            if not math.isfinite(values[key]):
                raise EffectError(f"effect {self.name!r}: parameter {key} must be finite")
        return values

    def spec(self, values: Mapping[str, float]) -> str:
        """Canonical spec string, parameters in declaration order."""
        parts = [self.name] + [f"{p.name}={values[p.name]:g}" for p in self.params]
        return ":".join(parts)


EFFECTS: dict[str, RigEffect] = {}


def effect(name: str, group: str, summary: str, **params: tuple[float, str]) -> Callable[[Apply], Apply]:
    """Register ``fn(config, values, rng)`` as effect ``name`` with parameters ``key=(default, doc)``."""

    def register(fn: Apply) -> Apply:
        if name in EFFECTS:
            raise RuntimeError(f"effect {name!r} registered twice")
        EFFECTS[name] = RigEffect(name, group, summary, tuple(Param(k, d, doc) for k, (d, doc) in params.items()), fn)
        return fn

    return register


EffectSpec = str | tuple[str, Mapping[str, float]]


def parse_effects(specs: Sequence[EffectSpec] | str) -> list[tuple[RigEffect, dict[str, float]]]:
    """Specs (strings in the syntax above, or ``(name, {param: value})`` pairs) → effects + values."""
    if isinstance(specs, str):
        specs = [specs]
    pending: list[tuple[str, dict[str, str]]] = []
    for spec in specs:
        if isinstance(spec, tuple):
            name, params = spec
            pending.append((str(name), dict(params)))
            continue
        for token in str(spec).split(","):
            token = token.strip()
            if not token:
                continue
            parts = [p.strip() for p in token.split(":")]
            if "=" in parts[0]:
                if not pending:
                    raise EffectError(f"effect spec {token!r}: parameter given before any effect name")
                target = pending[-1][1]
            else:
                pending.append((parts[0], {}))
                target, parts = pending[-1][1], parts[1:]
            for part in parts:
                key, sep, value = part.partition("=")
                if not sep or not key.strip():
                    raise EffectError(f"effect spec {token!r}: expected key=value, got {part!r}")
                target[key.strip()] = value.strip()
    parsed = []
    for name, given in pending:
        if name not in EFFECTS:
            raise EffectError(f"unknown effect {name!r} (known: {', '.join(sorted(EFFECTS))})")
        eff = EFFECTS[name]
        parsed.append((eff, eff.resolve(given)))
    return parsed


def apply_effects(config: "RigConfig", specs: Sequence[EffectSpec] | str, seed: int, record: bool = True) -> None:
    """Apply effects in order; their canonical specs are appended to ``config.effects`` if ``record``."""
    from graytrack.drivers.sim.rig import rng_for

    for eff, values in parse_effects(specs):
        eff.apply(config, values, rng_for(seed, "effect", eff.name))
        if record:
            config.effects.append(eff.spec(values))


def _positive(name: str, key: str, value: float, allow_zero: bool = False) -> float:
    if value < 0 or (value == 0 and not allow_zero):
        raise EffectError(f"effect {name!r}: {key} must be {'≥' if allow_zero else '>'} 0, got {value:g}")
    return value


def _count(name: str, key: str, value: float, low: int, high: int) -> int:
    """An integer parameter within the range a real rig can have (beyond it the simulation would
    only exhaust memory)."""
    n = int(round(value))
    if not low <= n <= high:
        raise EffectError(f"effect {name!r}: {key} must be {low}..{high}, got {value:g}")
    return n


def _field_span(config: "RigConfig") -> tuple[float, float]:
    """Target x range the camera sees over the stroke."""
    fov = config.optics.pixel_pitch_mm * config.optics.n_pixels
    lo, hi = config.stroke_mm
    return lo + config.optics.x_offset_mm, hi + config.optics.x_offset_mm + fov


# ----- target ----------------------------------------------------------------------------------


@effect("harmonics", "target",
        "Print distortion: 2nd and 3rd harmonics added to the profile, relative to its fundamental.",
        h2=(0.05, "2nd-harmonic amplitude / fundamental"), h3=(0.02, "3rd-harmonic amplitude / fundamental"),
        phase2_deg=(0.0, "phase of the 2nd harmonic"), phase3_deg=(0.0, "phase of the 3rd harmonic"))
def _harmonics(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    for order in (2, 3):
        if v[f"h{order}"]:
            config.target.harmonics.append((order, v[f"h{order}"], math.radians(v[f"phase{order}_deg"])))


@effect("print_gamma", "target",
        "Nonlinear print (dot gain): each period's profile normalised to [0,1] and raised to gamma.",
        gamma=(1.3, ">1 narrows the bright crests, <1 the dark troughs"))
def _print_gamma(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.target.print_gamma *= _positive("print_gamma", "gamma", v["gamma"])


@effect("pitch_scale", "target", "Pitch error as a scale: the printed period is nominal·(1 + ppm·1e-6).",
        ppm=(300.0, "scale error in parts per million"))
def _pitch_scale(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.target.scale_error = (1 + config.target.scale_error) * (1 + v["ppm"] * 1e-6) - 1


@effect("chirp", "target", "Nonlinear pitch error: the print is warped by um·ξ^order over the field (ξ ∈ [-1, 1]).",
        um=(20.0, "peak position error of the print, µm"),
        order=(2.0, "2 = chirp (period changes linearly), 3 = S-shape"))
def _chirp(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    order = _count("chirp", "order (order 1 is pitch_scale)", v["order"], 2, 9)
    lo, hi = _field_span(config)
    config.target.chirp_mm += v["um"] * 1e-3
    config.target.chirp_order = order
    config.target.chirp_center_mm = 0.5 * (lo + hi)
    config.target.chirp_half_span_mm = 0.5 * (hi - lo)


@effect("target_growth", "target", "The print grows after calibration (paper in humidity, a film warming up): "
        "stretched by ppm about a fixed point from start_s on, over ramp_s (0: a step); the stage's grating does not "
        "see it, so the camera reads −ppm·(x − centre) against it.",
        ppm=(250.0, "growth, parts per million (negative: shrinks)"),
        at=(0.5, "fixed point along the field seen over the stroke, 0..1 (0.5: the target's centre)"),
        start_s=(0.0, "when the growth begins, s"), ramp_s=(0.0, "how long it takes, s (0: a step)"))
def _target_growth(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not 0 <= v["at"] <= 1:
        raise EffectError("effect 'target_growth': at must be in [0, 1]")
    if v["ppm"] <= -1e6:
        raise EffectError("effect 'target_growth': ppm must be > -1e6 (the print cannot shrink to nothing)")
    lo, hi = _field_span(config)
    config.target.growths.append(Growth(v["ppm"], lo + v["at"] * (hi - lo), v["start_s"],
                                        _positive("target_growth", "ramp_s", v["ramp_s"], True)))


def _defect_y_range(config: "RigConfig", margin: float) -> tuple[float, float]:
    pitch = config.optics.pixel_pitch_mm
    return -margin, pitch * (config.optics.n_rows - 1) + margin


@effect("dust", "target",
        "Dust on the target: dark Gaussian spots fixed to the target, placed at random over the field.",
        count=(8.0, "number of spots"), size_um=(50.0, "spot sigma, µm"),
        depth=(0.3, "relative darkening at the centre"))
def _dust(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    size = _positive("dust", "size_um", v["size_um"]) * 1e-3
    lo, hi = _field_span(config)
    ylo, yhi = _defect_y_range(config, size)
    for _ in range(_count("dust", "count", v["count"], 0, 10_000)):
        config.target.defects.append(Defect("dust", rng.uniform(lo, hi), rng.uniform(ylo, yhi), size, v["depth"]))


@effect("dust_settling", "target", "Dust settling on the print during the run: dark specks from narrower than a "
        "pixel to a little wider, landing one by one at random places and times between start_s and start_s + over_s, "
        "then fixed to the print (they move with it past the camera).",
        count=(30.0, "specks on the field seen over the stroke by the end"),
        size_min_px=(0.2, "smallest speck sigma, pixel footprints"), size_max_px=(0.6, "largest, pixel footprints"),
        depth=(0.5, "relative darkening at a speck's centre"), start_s=(0.5, "when the first may land, s"),
        over_s=(8.0, "the span of time over which they land, s"))
def _dust_settling(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    pitch = config.optics.pixel_pitch_mm
    low = _positive("dust_settling", "size_min_px", v["size_min_px"]) * pitch
    high = _positive("dust_settling", "size_max_px", v["size_max_px"]) * pitch
    if high < low:
        raise EffectError("effect 'dust_settling': need size_min_px ≤ size_max_px")
    count = _count("dust_settling", "count", v["count"], 0, 10_000)
    lo, hi = _field_span(config)
    ylo, yhi = _defect_y_range(config, low)
    landed = np.sort(_positive("dust_settling", "start_s", v["start_s"], True)
                     + rng.uniform(0.0, _positive("dust_settling", "over_s", v["over_s"], True), count))
    for when in landed:
        config.target.defects.append(Defect("dust", rng.uniform(lo, hi), rng.uniform(ylo, yhi), rng.uniform(low, high),
                                            v["depth"], 0.0, float(when)))


@effect("scratches", "target", "Scratches across the target: thin lines (bright when depth<0) at a small angle to y.",
        count=(2.0, "number of scratches"), width_um=(15.0, "line sigma, µm"),
        depth=(-0.25, "relative darkening (<0 brightens)"),
        angle_deg=(5.0, "angle from the target's y axis"))
def _scratches(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    width = _positive("scratches", "width_um", v["width_um"]) * 1e-3
    lo, hi = _field_span(config)
    for _ in range(_count("scratches", "count", v["count"], 0, 1_000)):
        config.target.defects.append(
            Defect("scratch", rng.uniform(lo, hi), 0.0, width, v["depth"], math.radians(v["angle_deg"]))
        )


# ----- illumination --------------------------------------------------------------------------


@effect("gradient", "illumination",
        "Uneven light fixed to the target: gain 1 + slope·dx + curvature·dx² along the stroke.",
        per_10mm=(0.05, "relative gain change per 10 mm"),
        curvature=(0.0, "relative gain change at ±10 mm from the centre"))
def _gradient(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    lo, hi = _field_span(config)
    config.illumination.gradient_per_mm += v["per_10mm"] / 10.0
    config.illumination.gradient_curvature_per_mm2 += v["curvature"] / 100.0
    config.illumination.gradient_center_mm = 0.5 * (lo + hi)


@effect("vignetting", "illumination",
        "Light fall-off fixed to the camera: gain 1 − edge·ρ² (ρ = radius / sensor half-width).",
        edge=(0.08, "relative loss at the half-width"))
def _vignetting(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.illumination.vignetting += v["edge"]


@effect("vignetting_change", "illumination", "The field's vignetting changes after calibration (the lens's aperture "
        "ring knocked, a lamp riding on the camera moved): from start_s each pixel's gain changes by −delta·ρ² "
        "(ρ = radius / sensor half-width, as for vignetting), reached over ramp_s (0: a step), then kept; fixed to "
        "the camera's pixels.",
        delta=(0.05, "relative gain change at the sensor's half-width (> 0: darker edges)"),
        start_s=(2.0, "when the change begins, s"), ramp_s=(1.0, "how long it takes, s (0: a step)"))
def _vignetting_change(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    side = config.camera_side
    delta = side.vignetting_delta + v["delta"]
    if delta * float(pixel_geometry(config.optics).radius2.max()) >= 1.0:
        raise EffectError("effect 'vignetting_change': delta would take all the light from the ROI's corner")
    side.vignetting_delta = delta
    side.vignetting_start_s = v["start_s"]
    side.vignetting_ramp_s = _positive("vignetting_change", "ramp_s", v["ramp_s"], True)


@effect("flicker", "illumination",
        "Lamp flicker at 2×mains: each frame's light scaled by 1 + depth·sinc(2fT)·cos(2π·2f·t + φ).",
        mains_hz=(50.0, "mains frequency"), depth=(0.02, "relative modulation of the light"),
        phase_deg=(-1.0, "phase φ; negative = random"))
def _flicker(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    ill = config.illumination
    ill.mains_hz = _positive("flicker", "mains_hz", v["mains_hz"])
    ill.flicker_depth = v["depth"]
    ill.flicker_phase_rad = math.radians(v["phase_deg"]) if v["phase_deg"] >= 0 else rng.uniform(0, 2 * math.pi)


@effect("light_change", "illumination", "The light changes during the run (room light switched on, a lamp dimming): "
        "from start_s on the lamp gives gain × its light and stray light adds ambient_gray evenly; ramp_s spreads the "
        "change over time (0: a step).",
        gain=(0.9, "lamp light after the change, relative"), ambient_gray=(6.0, "stray light added, gray"),
        start_s=(0.0, "when the change begins, s"), ramp_s=(0.0, "how long it takes, s (0: a step)"))
def _light_change(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    ill = config.illumination
    ill.level_gain = _positive("light_change", "gain", v["gain"])
    ill.ambient_gray = v["ambient_gray"]
    ill.level_start_s = v["start_s"]
    ill.level_ramp_s = _positive("light_change", "ramp_s", v["ramp_s"], True)


@effect("moving_shadow", "illumination", "A cable's shadow swinging across the field between the lamp and the print "
        "(fixed to neither camera nor print): a band `width_mm` wide with soft edges (penumbra σ `edge_mm`), "
        "`depth` of the light lost in its core, crossing the field in `pass_s`, `passes` times (back and forth) "
        "every `period_s` from `start_s` on.",
        depth=(0.33, "relative light lost in the band's core"), width_mm=(3.0, "band width on the print plane, mm"),
        edge_mm=(1.0, "softness of each edge (penumbra σ), mm"), pass_s=(1.0, "time of one pass across the field, s"),
        passes=(3.0, "number of passes"), period_s=(4.0, "time between passes, s"),
        start_s=(1.0, "when the first pass begins, s"))
def _moving_shadow(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not 0 <= v["depth"] < 1:
        raise EffectError("effect 'moving_shadow': depth must be in [0, 1)")
    pass_s = _positive("moving_shadow", "pass_s", v["pass_s"])
    if v["period_s"] < pass_s:
        raise EffectError("effect 'moving_shadow': period_s must be at least pass_s (one pass at a time)")
    width, edge = (_positive("moving_shadow", key, v[key]) for key in ("width_mm", "edge_mm"))
    passes = _count("moving_shadow", "passes", v["passes"], 0, 10000)
    config.illumination.shadow = ShadowConfig(v["depth"], width, edge, pass_s, passes, v["period_s"], v["start_s"])


# ----- optics ----------------------------------------------------------------------------------


@effect("distortion", "optics", "Radial lens distortion about the sensor centre: positions × (1 + k1·ρ²).",
        k1=(0.01, "relative stretch at the sensor half-width (<0: barrel)"))
def _distortion(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.optics.distortion_k1 += v["k1"]


@effect("defocus", "optics", "Defocus: Gaussian blur on the target; harmonic i loses exp(−2π²σ²(i/τ)²).",
        sigma_um=(150.0, "blur sigma on the target, µm"))
def _defocus(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    s = config.optics.defocus_sigma_mm
    config.optics.defocus_sigma_mm = math.hypot(s, _positive("defocus", "sigma_um", v["sigma_um"], True) * 1e-3)


@effect("focus_drift", "optics",
        "Focus drifting during the run (a lens mount warming up): from start_s the blur σ on the "
        "target moves by px pixel footprints (px·α·d; >0 blurrier, <0 sharper, never below σ = 0: a sharper image "
        "needs a base defocus to lose), ramped in over ramp_s (0: a step).",
        px=(0.5, "change of the blur σ, pixels"), start_s=(0.0, "when the change begins, s"),
        ramp_s=(0.0, "how long it takes, s (0: a step)"))
def _focus_drift(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    _move_focus(config, v)
    config.optics.focus_ramp_s = _positive("focus_drift", "ramp_s", v["ramp_s"], True)


def _move_focus(config: "RigConfig", v: dict[str, float]) -> None:
    """The blur σ's change (px pixel footprints) and when it begins: what a drift and a cycle share."""
    config.optics.focus_drift_mm += v["px"] * config.optics.pixel_pitch_mm
    config.optics.focus_start_s = v["start_s"]


@effect("focus_cycle", "optics", "Focus coming and going during the run (a lens mount warming and cooling with "
        "the room or a duty cycle): from start_s the blur σ on the target moves by up to px pixel footprints and back, "
        "as (1 − cos 2πt/period_s)/2: blurrier (px > 0) or sharper (px < 0, from a base defocus) and back again.",
        px=(0.5, "largest change of the blur σ, pixels"), period_s=(10.0, "one cycle, s"),
        start_s=(0.0, "when the first cycle begins, s"))
def _focus_cycle(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    _move_focus(config, v)
    config.optics.focus_cycle_s = _positive("focus_cycle", "period_s", v["period_s"])


@effect("tilt", "optics",
        "Camera rows tilted against the axis of motion: row r sees the target shifted by −r·α·d·sin(angle).",
        deg=(0.5, "tilt angle, degrees"))
def _tilt(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.optics.tilt_rad += math.radians(v["deg"])


@effect("mirrored", "optics", "The pixel axis reversed (camera mounted the other way round, ReverseX on): "
        "increasing u sees decreasing target x (the recording contract wants the opposite).")
def _mirrored(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.optics.mirrored = not config.optics.mirrored


@effect("magnification", "optics", "The lens images the target larger or smaller than the rig's nominal α·d says "
        "(refocused, a spacer changed): the true pixel footprint is nominal·(1 + percent/100).",
        percent=(10.0, "footprint error, %"))
def _magnification(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not v["percent"] > -100:
        raise EffectError("effect 'magnification': percent must be above -100")
    config.optics.magnification_error = (1 + config.optics.magnification_error) * (1 + v["percent"] / 100) - 1


@effect("magnification_drift", "optics", "The lens's magnification drifting during the run (warming up, a "
        "temperature cycle): every pixel's footprint scales by 1 + m(t) about the optical axis, axis_px pixel "
        "footprints from the ROI's centre along the line, so the image stretches across the line and slides by "
        "m·axis while the stage stands. m(t) reaches ppm over ramp_s from start_s (0: a step), or with cycle_s > 0 "
        "comes and goes: ppm·(1 − cos 2π(t − start_s)/cycle_s)/2.",
        ppm=(1500.0, "change of the footprint, parts per million (1500: 0.15 %)"),
        axis_px=(300.0, "the optical axis's place from the ROI's centre, pixel footprints (> 0: towards larger u)"),
        start_s=(0.0, "when the drift begins, s"), ramp_s=(10.0, "how long a ramp takes, s (0: a step)"),
        cycle_s=(0.0, "a cycle's period, s (0: a ramp)"))
def _magnification_drift(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not v["ppm"] > -1e6:
        raise EffectError("effect 'magnification_drift': ppm must be above -1e6")
    optics = config.optics
    optics.magnification_drift = (1 + optics.magnification_drift) * (1 + v["ppm"] * 1e-6) - 1
    optics.magnification_axis_mm = v["axis_px"] * optics.pixel_pitch_mm
    optics.magnification_start_s = v["start_s"]
    optics.magnification_ramp_s = _positive("magnification_drift", "ramp_s", v["ramp_s"], True)
    optics.magnification_cycle_s = _positive("magnification_drift", "cycle_s", v["cycle_s"], True)


@effect("knock", "mechanics", "The camera knocked on its mount during the run: from at_s on, the image sits "
        "um further along the axis against the carriage and its rows are turned by deg about the ROI's centre "
        "(a strip's rows then shift against each other); the carriage, and the grating, do not move.",
        um=(40.0, "the image's jump along the axis against the carriage, µm"),
        deg=(0.2, "the rows' turn, degrees (a strip only shows it)"), at_s=(2.0, "when, s"))
def _knock(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    optics = config.optics
    optics.knock_mm += v["um"] * 1e-3
    optics.knock_rad += math.radians(v["deg"])
    optics.knock_s = _positive("knock", "at_s", v["at_s"], True)


@effect("off_target", "optics", "The ROI partly off the print: its last `share` of columns (and its first `rows` "
        "rows) look past the print's edge at a plain surface of `gray`.",
        share=(0.3, "share of the line's columns off the print, 0..1"), rows=(0.0, "rows off the print"),
        gray=(200.0, "the plain surface's light, gray"))
def _off_target(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not 0 <= v["share"] <= 1:
        raise EffectError("effect 'off_target': share must be in [0, 1]")
    config.optics.off_target_cols = int(round(v["share"] * config.optics.n_pixels))
    config.optics.off_target_rows = _count("off_target", "rows", v["rows"], 0, config.optics.n_rows)
    config.optics.background_gray = _positive("off_target", "gray", v["gray"], True)


@effect("window_dust", "optics", "Dust landing on the camera's window (the cover glass over the sensor) during the "
        "run: the window is out of focus, so each speck is a soft dark blob over rows and pixels (Gaussian σ between "
        "sigma_min_px and sigma_max_px, taking depth_min..depth_max of the light at its centre) fixed to the pixels "
        "whatever the stage does. They land one by one at random places and at random times between start_s and "
        "start_s + over_s, and stay. at_rest=1: each lands only on a frame taken while the stage stands still (the "
        "first at or after its time): until the stage moves it looks like a mark on the print.",
        count=(6.0, "number of specks"), sigma_min_px=(1.0, "narrowest speck's σ, pixels"),
        sigma_max_px=(2.5, "widest speck's σ, pixels"), depth_min=(0.2, "least share of the light a speck takes"),
        depth_max=(0.5, "most share of the light a speck takes"), start_s=(1.0, "when the first may land, s"),
        over_s=(6.0, "the span of time over which they land, s"),
        at_rest=(0.0, "1: land only while the stage is at rest, 0: whatever it does"))
def _window_dust(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    low, high = (_positive("window_dust", key, v[key]) for key in ("sigma_min_px", "sigma_max_px"))
    if high < low:
        raise EffectError("effect 'window_dust': need sigma_min_px ≤ sigma_max_px")
    if not 0 <= v["depth_min"] <= v["depth_max"] < 1:
        raise EffectError("effect 'window_dust': need 0 ≤ depth_min ≤ depth_max < 1")
    if v["at_rest"] not in (0.0, 1.0):
        raise EffectError("effect 'window_dust': at_rest must be 0 or 1")
    count = _count("window_dust", "count", v["count"], 0, 1_000)
    side = config.camera_side
    if side.specks and bool(v["at_rest"]) != side.at_rest:
        raise EffectError("effect 'window_dust': specks landing at rest and at any time cannot be mixed")
    side.at_rest = bool(v["at_rest"])
    start = _positive("window_dust", "start_s", v["start_s"], True)
    times = np.sort(start + rng.uniform(0.0, _positive("window_dust", "over_s", v["over_s"], True), count))
    for when in times:
        side.specks.append(WindowSpeck(rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0), rng.uniform(low, high),
                                       rng.uniform(v["depth_min"], v["depth_max"]), float(when)))


@effect("veil", "optics", "A veil forming on the camera's window during the run (condensation on a cold window, a "
        "film of oil) and staying: over the cover share of the line at one end it takes depth of the light and "
        "scatters scatter_gray of the lamp's light into the pixels, with a soft edge edge_px wide (a cosine taper: "
        "the window is out of focus); it arrives at start_s over rise_s; fixed to the camera's pixels, every row.",
        depth=(0.25, "share of the light it takes where it covers"),
        scatter_gray=(3.0, "the lamp's light it scatters into the covered pixels, gray"),
        cover=(0.4, "share of the line's pixels under it, 0..1"),
        side=(1.0, "which end it covers: 0 from the first pixel, 1 from the last"),
        edge_px=(8.0, "width of its soft edge, pixels (0: sharp)"), start_s=(2.0, "when it begins to form, s"),
        rise_s=(0.5, "how long it takes to form, s (0: at once)"))
def _veil(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not 0 <= v["depth"] < 1:
        raise EffectError("effect 'veil': depth must be in [0, 1)")
    if not 0 <= v["cover"] <= 1:
        raise EffectError("effect 'veil': cover must be in [0, 1]")
    if v["side"] not in (0.0, 1.0):
        raise EffectError("effect 'veil': side must be 0 or 1")
    config.camera_side.veil = VeilConfig(v["depth"], v["scatter_gray"], v["cover"], int(v["side"]),
                                         _positive("veil", "edge_px", v["edge_px"], True), v["start_s"],
                                         _positive("veil", "rise_s", v["rise_s"], True))


@effect("motion_blur", "optics", "Longer exposure: the moving profile is integrated over it (amplitude × sinc(v·T/τ)).",
        exposure_ms=(20.0, "exposure time, ms"))
def _motion_blur(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.timing.exposure_s = _positive("motion_blur", "exposure_ms", v["exposure_ms"], True) * 1e-3


# ----- sensor ----------------------------------------------------------------------------------


@effect("prnu", "sensor", "Pixel response non-uniformity: a gain per physical pixel, 1 + sigma·N(0,1).",
        sigma=(0.01, "relative gain spread"))
def _prnu(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.sensor.prnu_sigma = _positive("prnu", "sigma", v["sigma"], True)


@effect("dsnu", "sensor", "Dark signal non-uniformity: an offset per physical pixel, sigma·N(0,1) gray.",
        sigma=(1.0, "offset spread, gray"))
def _dsnu(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.sensor.dsnu_sigma_gray = _positive("dsnu", "sigma", v["sigma"], True)


@effect("shot_noise", "sensor", "Photon shot noise: variance = gray·255/full_well (gray²).",
        full_well=(10000.0, "electrons at full scale"))
def _shot_noise(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.sensor.full_well_e = _positive("shot_noise", "full_well", v["full_well"])


@effect("photon_transfer", "sensor", "A sensor described as EMVA 1288 does: full well and read noise in electrons, "
        "bit depth, black level; conversion gain 2^bits / full well (DN per electron); replaces the read noise.",
        full_well=(32000.0, "electrons at full scale"), read_e=(12.0, "read noise, electrons rms"),
        bits=(8.0, "bit depth of the readout, 1..16"), black_gray=(4.0, "black level, 8-bit-equivalent gray"))
def _photon_transfer(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    full_well = _positive("photon_transfer", "full_well", v["full_well"])
    config.sensor.full_well_e = full_well
    config.sensor.read_noise_gray = _positive("photon_transfer", "read_e", v["read_e"], True) * 255.0 / full_well
    config.sensor.black_level_gray = _positive("photon_transfer", "black_gray", v["black_gray"], True)
    _quantize(config, {"bits": v["bits"]}, rng)


@effect("bad_pixels", "sensor", "Defective pixels at random places of the ROI (or side by side from row/pixel): "
        "stuck high, dead (stuck at 0), hot (an offset), noisy; from time start_s on.",
        stuck=(1.0, "pixels stuck at full scale"), dead=(1.0, "pixels stuck at 0"), hot=(1.0, "hot pixels"),
        noisy=(0.0, "noisy pixels"), hot_gray=(40.0, "offset of a hot pixel, gray"),
        noisy_gray=(8.0, "extra noise of a noisy pixel, gray rms"), start_s=(0.0, "time they go bad, s"),
        row=(-1.0, "row of the first one (-1: random places)"), pixel=(-1.0, "pixel of the first one"))
def _bad_pixels(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    kinds = [("stuck", FULL_SCALE_GRAY)] * int(v["stuck"]) + [("stuck", 0.0)] * int(v["dead"]) + \
        [("hot", v["hot_gray"])] * int(v["hot"]) + [("noisy", v["noisy_gray"])] * int(v["noisy"])
    rows, width = config.optics.n_rows, config.optics.n_pixels
    if len(kinds) > rows * width:
        raise EffectError(f"effect 'bad_pixels': {len(kinds)} bad pixels do not fit in {rows} × {width}")
    if v["pixel"] >= 0:
        start = int(v["row"]) * width + int(v["pixel"])
        if not 0 <= start <= rows * width - len(kinds) or v["row"] < 0:
            raise EffectError("effect 'bad_pixels': row/pixel put the bad pixels outside the ROI")
        places = np.arange(start, start + len(kinds))
    else:
        places = rng.choice(rows * width, size=len(kinds), replace=False)
    for (kind, value), place in zip(kinds, places):
        config.sensor.bad_pixels.append(BadPixel(kind, int(place // width), int(place % width), value, v["start_s"]))


@effect("read_noise", "sensor", "Gaussian read noise per pixel and frame (replaces the scenario's).",
        gray=(0.7, "standard deviation, gray"))
def _read_noise(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.sensor.read_noise_gray = _positive("read_noise", "gray", v["gray"], True)


@effect("quantize", "sensor", "Digitise to a bit depth (uint8 up to 8 bits, uint16 above); clips at full scale.",
        bits=(8.0, "bit depth, 1..16"))
def _quantize(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.sensor.bit_depth = _count("quantize", "bits", v["bits"], 1, 16)


@effect("sensor_gamma", "sensor", "Camera output gamma: out = 255·(in/255)^gamma.", gamma=(0.8, "exponent"))
def _sensor_gamma(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.sensor.gamma *= _positive("sensor_gamma", "gamma", v["gamma"])


@effect("saturation", "sensor", "Too much gain: the signal is scaled and clipped at full scale (255).",
        gain=(1.4, "analog gain before the clip"))
def _saturation(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.sensor.gain *= _positive("saturation", "gain", v["gain"])
    config.sensor.clip = True


@effect("rows", "sensor", "ROI strip height: R rows × n pixels taken from the sensor.", n=(16.0, "number of rows"))
def _rows(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    n = _count("rows", "n (a sensor's ROI strip)", v["n"], 1, 4096)
    config.optics.n_rows = n
    if config.optics.sensor_height is not None:
        config.optics.sensor_height = max(config.optics.sensor_height, config.optics.roi_y + n)


# ----- stage, grating, timing --------------------------------------------------------------------


@effect("following_error", "stage", "Weak servo: lower bandwidth and velocity feed-forward; lag 2ζ(1−kv)·v/ω.",
        bandwidth_hz=(15.0, "servo natural frequency"), kv=(0.0, "velocity feed-forward, 0..1"))
def _following_error(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.stage.bandwidth_hz = _positive("following_error", "bandwidth_hz", v["bandwidth_hz"])
    config.stage.velocity_feedforward = v["kv"]


@effect("settling", "stage", "Underdamped servo: the stage rings after each acceleration change before settling.",
        damping=(0.15, "damping ratio ζ"), bandwidth_hz=(40.0, "servo natural frequency"))
def _settling(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.stage.damping = _positive("settling", "damping", v["damping"])
    config.stage.bandwidth_hz = _positive("settling", "bandwidth_hz", v["bandwidth_hz"])
    config.stage.acceleration_feedforward = 0.0


@effect("grating_resolution", "grating", "Reference quantised to a coarser step.", um=(1.0, "resolution, µm"))
def _grating_resolution(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.grating.resolution_mm = _positive("grating_resolution", "um", v["um"], True) * 1e-3


@effect("cyclic_error", "grating", "Grating interpolation error: amplitude·sin(2π x / period) added to the reference.",
        nm=(200.0, "amplitude, nm"), period_um=(20.0, "grating signal period, µm"))
def _cyclic_error(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.grating.cyclic_amplitude_mm = v["nm"] * 1e-6
    config.grating.cyclic_period_mm = _positive("cyclic_error", "period_um", v["period_um"]) * 1e-3
    config.grating.cyclic_phase_rad = rng.uniform(0, 2 * math.pi)


@effect("grating_latency", "grating", "The readout reports where the stage was a fixed time earlier: error −v·latency.",
        ms=(1.0, "latency of the position readout, ms"))
def _grating_latency(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.grating.latency_s = _positive("grating_latency", "ms", v["ms"], True) * 1e-3


@effect("time_skew", "timing", "Reference latched later than mid-exposure by a fixed time: its error is v·skew.",
        ms=(2.0, "latch minus exposure mid-point, ms (negative: earlier)"))
def _time_skew(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.timing.latch_skew_s += v["ms"] * 1e-3


@effect("jitter", "timing",
        "Exposure instants jitter about the frame clock that latches the reference: error v·N(0, σ).",
        us=(500.0, "jitter standard deviation, µs"))
def _jitter(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.timing.trigger_jitter_s = _positive("jitter", "us", v["us"], True) * 1e-6


@effect("rolling_shutter", "timing", "A rolling shutter: each row is exposed `line_us` after the row above (the "
        "rows centred on the frame's mid-exposure), so in motion row r sees the print v·line_us·r further on.",
        line_us=(20.0, "time between successive rows' exposures, µs"))
def _rolling_shutter(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.timing.line_time_s = _positive("rolling_shutter", "line_us", v["line_us"], True) * 1e-6


@effect("timestamp_jitter", "timing", "Recorded frame times noisy about the true exposure (image and reference agree).",
        us=(200.0, "timestamp noise standard deviation, µs"))
def _timestamp_jitter(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.timing.timestamp_jitter_s = _positive("timestamp_jitter", "us", v["us"], True) * 1e-6


@effect("dropped_frames", "timing", "Frames lost at random (gaps in t).", p=(0.05, "probability a frame is dropped"))
def _dropped_frames(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not 0 <= v["p"] < 1:
        raise EffectError("effect 'dropped_frames': p must be in [0, 1)")
    config.timing.drop_probability = v["p"]


@effect("frame_rate", "timing", "Frame rate (the exposure is capped at the frame period).",
        hz=(1000.0, "frames per second"))
def _frame_rate(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.timing.frame_rate_hz = _positive("frame_rate", "hz", v["hz"])
    config.timing.exposure_s = min(config.timing.exposure_s, 1.0 / v["hz"])


# ----- effects found by red-teaming the closed loop (light, pixels, print, optics, timing) --------


@effect("glare", "illumination",
        "A bright blob fixed to the camera (a reflection in the lens or a window): stray light "
        "added to the image, Gaussian about a point of the ROI; it dims and flickers with the lamp.",
        gray=(20.0, "stray light at the centre, gray"), at=(0.7, "centre along the line, fraction of the ROI width"),
        row=(0.5, "centre across the rows, fraction of the ROI height"), sigma_px=(8.0, "size, pixels"))
def _glare(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    ill = config.illumination
    ill.glare_gray = v["gray"]
    ill.glare_center = (v["at"], v["row"])
    ill.glare_sigma_px = _positive("glare", "sigma_px", v["sigma_px"])


@effect("gain_hunting", "sensor", "Auto-exposure/auto-gain hunting: the camera's gain swings frame to frame, "
        "1 + depth·sin(2π·hz·t + φ), in steps of `step` (a coarse gain register).",
        depth=(0.05, "relative swing of the gain"), hz=(1.5, "hunting frequency"),
        step=(0.01, "gain step, relative (0: smooth)"), phase_deg=(-1.0, "phase φ; negative = random"))
def _gain_hunting(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    sensor = config.sensor
    if not 0 <= v["depth"] < 1:
        raise EffectError("effect 'gain_hunting': depth must be in [0, 1)")
    sensor.gain_hunt_depth = v["depth"]
    sensor.gain_hunt_hz = _positive("gain_hunting", "hz", v["hz"])
    sensor.gain_hunt_step = _positive("gain_hunting", "step", v["step"], True)
    sensor.gain_hunt_phase_rad = math.radians(v["phase_deg"]) if v["phase_deg"] >= 0 else rng.uniform(0, 2 * math.pi)


@effect("telegraph_pixels", "sensor",
        "Random-telegraph (flickering) pixels: a charge trap makes each of `count` pixels "
        "jump by `gray` and back at random instants, `rate_hz` flips per second on average.",
        count=(3.0, "number of flickering pixels"), gray=(6.0, "size of the jump, gray"),
        rate_hz=(4.0, "mean flips per second"))
def _telegraph_pixels(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    rows, width = config.optics.n_rows, config.optics.n_pixels
    count = _count("telegraph_pixels", "count", v["count"], 0, rows * width)
    rate = _positive("telegraph_pixels", "rate_hz", v["rate_hz"])
    cycle = 600.0  # the flips drawn for ten minutes, then repeated: no recording notices
    for place in rng.choice(rows * width, size=count, replace=False):
        n_flips = int(rng.poisson(rate * cycle)) // 2 * 2  # even: the pattern repeats seamlessly
        flips = tuple(float(t) for t in np.sort(rng.uniform(0.0, cycle, n_flips)))
        config.sensor.bad_pixels.append(
            BadPixel("telegraph", int(place // width), int(place % width), v["gray"], 0.0, flips, cycle))


@effect("row_banding", "sensor", "Row banding: each frame every row gets an offset of its own (the readout's "
        "reference drifts line by line), Gaussian, common to all pixels of the row.",
        gray=(1.0, "offset standard deviation, gray"))
def _row_banding(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.sensor.row_noise_gray = _positive("row_banding", "gray", v["gray"], True)


@effect("mono12_in_16", "sensor", "Mono12 data left-aligned in 16-bit words (values step by 16) with a camera "
        "black level: what a machine-vision camera set to Mono16 delivers.",
        black_gray=(16.0, "black level, 8-bit-equivalent gray"), read_e=(6.0, "read noise, electrons rms"),
        full_well=(10000.0, "electrons at full scale"))
def _mono12_in_16(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    _photon_transfer(config, {"full_well": v["full_well"], "read_e": v["read_e"], "bits": 16.0,
                              "black_gray": v["black_gray"]}, rng)
    config.sensor.lsb_shift = 4


@effect("smudge", "target", "A local print defect: an ink smudge darkening part of one period, across the whole "
        "height, somewhere in the stroke.",
        at=(0.6, "place along the field seen over the stroke, 0..1"), width_um=(700.0, "Gaussian sigma, µm"),
        depth=(0.35, "relative darkening at its centre"))
def _smudge(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not 0 <= v["at"] <= 1:
        raise EffectError("effect 'smudge': at must be in [0, 1]")
    lo, hi = _field_span(config)
    width = _positive("smudge", "width_um", v["width_um"]) * 1e-3
    config.target.defects.append(Defect("scratch", lo + v["at"] * (hi - lo), 0.0, width, v["depth"], 0.0))


@effect("vibration", "stage", "A structural vibration on the stage (a fan, a pump, a limit cycle): "
        "amplitude·sin(2π·hz·t); the grating sees it, the camera averages it over the exposure.",
        um=(2.0, "amplitude, µm"), hz=(180.0, "frequency"), phase_deg=(-1.0, "phase; negative = random"))
def _vibration(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    stage = config.stage
    stage.vibration_mm = _positive("vibration", "um", v["um"], True) * 1e-3
    stage.vibration_hz = _positive("vibration", "hz", v["hz"])
    stage.vibration_phase_rad = math.radians(v["phase_deg"]) if v["phase_deg"] >= 0 else rng.uniform(0, 2 * math.pi)


@effect("glints", "illumination", "Specular glints: the lamp mirrored by a glossy spot of the print, a bright Gaussian "
        "blob a few pixels wide (and rows high) pinned to that spot, lasting 1..4 frames, on a share p of the frames; "
        "bright ones saturate the sensor. A later glints spec replaces the earlier one (a run glinting more often).",
        p=(0.05, "share of frames with a glint"), gray_min=(80.0, "weakest peak, gray"),
        gray_max=(200.0, "brightest peak, gray"), sigma_px=(1.5, "blob size (Gaussian sigma), pixels"))
def _glints(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not 0 <= v["p"] < 1:
        raise EffectError("effect 'glints': p must be in [0, 1)")
    if not 0 <= v["gray_min"] <= v["gray_max"]:
        raise EffectError("effect 'glints': need 0 ≤ gray_min ≤ gray_max")
    cfg = config.glints
    cfg.probability = v["p"]
    cfg.gray_min, cfg.gray_max = v["gray_min"], v["gray_max"]
    cfg.sigma_px = _positive("glints", "sigma_px", v["sigma_px"])
    cfg.seed = int(rng.integers(0, 2**31))


@effect("duplicate_frames", "timing", "The driver delivers the previous image again with a new timestamp and "
        "reference reading (as USB drivers do when a frame is late).", p=(0.03, "probability per frame"))
def _duplicate_frames(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    if not 0 <= v["p"] < 1:
        raise EffectError("effect 'duplicate_frames': p must be in [0, 1)")
    config.timing.duplicate_probability = v["p"]


@effect("clock_drift", "timing", "A free-running camera whose clock runs fast (or slow) against the reference's: "
        "its exposures drift from the reference's latch by ppm·t.", ppm=(100.0, "clock rate error, parts per million"))
def _clock_drift(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.timing.clock_ppm = v["ppm"]


@effect("mjpeg", "sensor", "Lossy MJPEG stream (baseline JPEG of each 8-bit frame, 8×8 blocks from the ROI's "
        "corner, the standard luminance table scaled for the quality).", quality=(75.0, "JPEG quality, 1…100"))
def _mjpeg(config: "RigConfig", v: dict[str, float], rng: np.random.Generator) -> None:
    config.sensor.jpeg_quality = _count("mjpeg", "quality", v["quality"], 1, 100)
    config.sensor.bit_depth = 8  # an MJPEG stream carries 8-bit samples whatever the sensor digitises
