"""The estimator's tunables, each declared once with its unit and the reason it has its value.

A tunable is a physical rate (how fast a nuisance of the rig may drift between frames, as the
standard deviation of a random walk after one second), a prior (how little is known of a quantity
before any frame), or the one false-alarm rate every flag is tested at. Nothing else in the
estimator is a free number: thresholds follow from the false-alarm rate and the noise model.

``EstimatorSettings.describe()`` lists them as python-microscope's ``describe_settings`` does
(name, value, unit, reason), so a user, the daemon's config and the tests read the same table.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Tunable:
    """One declared number: its default, unit and why it has that value."""

    default: float
    unit: str
    reason: str
    low: float = 0.0  # the smallest value that makes physical sense (inclusive)
    high: float = math.inf


# The table of every tunable. A new state's rate is one entry here and one field below.
TUNABLES: dict[str, Tunable] = {
    "false_alarm": Tunable(
        1e-4, "1/frame",
        "the probability that a frame the model describes is flagged: one flag in 10,000 steady frames keeps a "
        "steady run flagged far below 1 %, and a frame 4σ off (6e-5 two-sided) is still caught",
        low=1e-12, high=0.1),
    "acceleration": Tunable(
        1000.0, "mm/s²",
        "the stage's acceleration, as white noise between frames: the fastest rig here oscillates 10 mm at 2 Hz "
        "(830 mm/s² peak); a frame at 50 fps is then barely tied to the last, at 1 kHz within ~0.5 µm",
        low=0.0),
    "stage_acceleration": Tunable(
        1000.0, "mm/s²",
        "the most the stage accelerates (its controller's ACC/DEC, or the peak its motion asks for; a recording "
        "that states it overrides this): without the grating, a step of the image against the carriage larger "
        "than such a motion makes between four frames is the camera moving on its mount (mount.py); a rig "
        "that does not say gets the fastest here's (830 mm/s² peak), which at 50 frames/s allows 300 µm",
        low=0.0),
    "stage_settle": Tunable(
        0.03, "s",
        "how long after a commanded phase of acceleration ends (a recording's stage_acceleration_phases) the stage "
        "may still accelerate as its servo catches up: a few periods of its bandwidth (an 80 Hz servo damped at 0.8 "
        "settles within 10 ms)", low=0.0),
    "stage_servo": Tunable(
        20.0, "mm/s²",
        "what a stage accelerates beyond its commands (its servo's overshoot, the floor's vibration) where its "
        "calibration's readings did not show more; with the commands known, a cruise or a rest allows only this "
        "(at 50 frames/s, 6 µm between four frames instead of the commanded most's 30 µm at 100 mm/s²)", low=0.0),
    "stage_jitter": Tunable(
        20e-3, "mm",
        "how far a frame's position may be off the path the frames before it drew, afresh each frame: the stage's "
        "ripple and the floor's vibration (µm), and what the image's model misses for a few frames (a light or a "
        "mark changing: tens of µm over less than a period); the path then keeps the stage's velocity, not each "
        "frame's pull: a tighter tie lets such a pull bend the path, and the frames after it inherit the bend",
        low=0.0),
    "stage_drift": Tunable(
        1.0, "mm/s²",
        "how much the stage's path bends between its commanded phases, as white acceleration (a servo holding its "
        "speed against friction and a cable's drag: its velocity wanders by tens of µm/s over a second; its "
        "ripple is the jitter); where the commands are not known, the path bends by the stage's acceleration",
        low=0.0),
    "gain_rate": Tunable(
        0.005, "1/√s",
        "the light's relative drift in a second while it drifts (a lamp warming, a camera's gain hunting in small "
        "steps); over less than a period of the print a light that wanders moves the position a little with it, so "
        "the light drifts only where its frames read it drifting (light_switch_rate), and a real change of the light "
        "is a jump", low=0.0),
    "gain_rate_holding": Tunable(
        1e-6, "1/√s",
        "the light's relative drift in a second while the lamp holds (a regulated lamp: a millionth); a light held "
        "costs the position nothing, one that wanders at the drifting rate costs a 16-row strip a sixth of its "
        "precision", low=0.0),
    "gain_prior": Tunable(
        0.05, "1", "the light at the first frame against calibration's (another day, another lamp setting)", low=0.0),
    "offset_rate": Tunable(
        0.1, "gray/√s", "stray light creeping in a second while the light drifts; a light switched is a jump",
        low=0.0),
    "offset_rate_holding": Tunable(1e-4, "gray/√s", "stray light creeping in a second while the room holds",
                                   low=0.0),
    "light_switch_rate": Tunable(
        3.0, "1/s",
        "how often the light passes between holding and drifting (the two modes' Markov chain): each frame's reading "
        "of the gain and offset is weighed under both modes' predictions and the frame is updated in the likelier; "
        "faster, a mode remembers less of the frames before (a third of a second here: a hunting camera or a shadow "
        "passing keeps the drift while it lasts, a steady lamp holds)", low=0.0),
    "offset_prior": Tunable(2.0, "gray", "stray light at the first frame against calibration's", low=0.0),
    "field_rate": Tunable(
        1e-5, "1/√s",
        "the light's shape across the line (a tilt and a bow of the illumination, relative) drifting in a second "
        "while nothing happens to the lamp; over less than a period of the print a light's tilt looks like a shift "
        "of the image, so a shape that wanders freely wanders the position with it: a real change is a jump",
        low=0.0),
    "field_prior": Tunable(2e-4, "1", "the light's shape at the first frame against calibration's", low=0.0),
    "field_changed_prior": Tunable(
        1e-2, "1",
        "the light's shape at the first frame where it changed since calibration (a lamp moved, an aperture knocked, "
        "light uneven along a print laid since: a percent across the line), the rival hypothesis of the first frames "
        "(core/estimator/shape_contest.py)", low=0.0),
    "stretch_changed_prior": Tunable(
        0.0, "1",
        "from the image alone, the magnification at the first frame where it changed since calibration (a lens "
        "refocused, a spacer changed: 0.1 for percents), a rival of its own in the first frames' contest "
        "(core/estimator/shape_contest.py); none by default: a model's own error at fixed places (a glare or a "
        "smudge calibrated in) reads as a stretch changed, and the stretch's rival took over steady runs there (a "
        "glare 2.05 -> 5.63 of its floor with 7 frames silent), where a lens refocused 10 % errs 64 µm with 17 "
        "frames silent without it and none with it", low=0.0),
    "shape_contest_frames": Tunable(
        30, "frames",
        "how many first frames the rig as calibrated and as changed (the light's shape; the magnification where "
        "stretch_changed_prior allows) are followed side by side before the "
        "one the evidence has not refuted stands (each costs a second update: a changed shape shows from the first "
        "frames, a clean run pays for these only); 0: the shape as calibrated, no contest", low=0),
    "sensor_floor_gray": Tunable(
        -math.inf, "gray",
        "the readout's floor: a sample at or below it sits clipped and carries no position, and is set aside (a "
        "recording that states its camera's range, its bit depth or a clip, sets it; -inf: the floor the model's "
        "calibration stated, if any)", low=-math.inf),
    "sensor_ceiling_gray": Tunable(
        math.inf, "gray",
        "the readout's ceiling, as the floor: a camera whose gain was raised since calibration saturates where its "
        "calibration did not (inf: the ceiling the model's calibration stated, if any)", low=-math.inf),
    "mains_hz": Tunable(
        50.0, "Hz",
        "the mains frequency the lamp runs on (60 where the grid is): a lamp on it flickers at twice it, which a "
        "camera of a few hundred frames a second samples at a phase that walks from frame to frame", low=0.0),
    "flicker_prior": Tunable(
        0.02, "1",
        "each part of the lamp's flicker at twice the mains at the first frame, relative to its light (a halogen's "
        "1-2 %; a fluorescent tube or a cheap LED driver more, which its frames then read; 0: a lamp on DC, no "
        "flicker state)", low=0.0),
    "flicker_rate": Tunable(
        0.3, "1/√s",
        "the flicker drifting in a second relative to its depth (its phase in radians: the grid's frequency a few "
        "hundredths of a hertz off nominal turns it by 0.1-0.6 rad a second; its depth as the lamp warms): a lamp "
        "without a flicker holds none, so a steady light costs nothing", low=0.0),
    "focus_rate": Tunable(
        1e-4, "px²/√s", "the blur variance drifting in a second while the lens holds (a mount warming over minutes)",
        low=0.0),
    "focus_prior": Tunable(
        1.0, "px²",
        "the blur at the first frame against calibration's (another day, a lens refocused or its mount warmer: a "
        "sixth of a pixel on a blur σ of 3 px is 1 px²); on a strip of a few rows the blur's harmonics tell it "
        "within a second, on one row over less than a period it trades with the light's gain and offset, which moves "
        "no position; narrower, a blur another day left would be taken for a drift, and followed past itself",
        low=0.0),
    "focus_drift_prior": Tunable(
        0.05, "px²/s",
        "how fast the blur variance may be drifting at the first frame (a lens settling after a refocus: a tenth of a "
        "pixel on a blur σ of 2 px within 10 s is 0.04 px²/s); 0: no drift state, the blur a random walk alone",
        low=0.0),
    "focus_drift_rate": Tunable(
        0.5, "px²/s/√s",
        "how fast the blur's drift itself may change in a second: a lens warming and cooling with a duty cycle of "
        "seconds (its blur σ 1.5 px out and back within 6 s turns its drift by ~0.5 px²/s in a second); slower "
        "warmings change it far less, and a step of the focus is a jump", low=0.0),
    "stretch_rate": Tunable(
        30e-6, "1/√s",
        "the magnification drifting in a second (a lens warming up changes it by ~1500 ppm over 10 s); without the "
        "grating its slide reaches the position through the lever, so a faster rate widens every bound of a steady "
        "run (at 100 ppm/√s the paper rig's bound grew by a half)", low=0.0),
    "stretch_prior": Tunable(5e-6, "1", "the magnification at the first frame against calibration's", low=0.0),
    "stretch_rate_most": Tunable(
        300e-6, "1/√s",
        "the fastest the magnification may drift (a lens warming in a draught, a focus ring settling: 0.15 % in 10 s "
        "is 1.6σ of it); the estimate follows the likely rate above, but without the grating no frame tells the "
        "slide it gives the image from a move of the stage, so the bound carries the stretch the frames cannot "
        "rule out at this rate", low=0.0),
    "place_rate": Tunable(
        0.05e-3, "mm/√s",
        "the camera creeping on its mount against the carriage in a second (a clamped mount: tens of nm); "
        "a knock is a jump, not this rate", low=0.0),
    "place_step_frames": Tunable(
        5, "frames",
        "read and checked, how many frames from the first of a run the grating refutes must disagree with it by one "
        "offset (within their noise, each explaining its own samples) before the camera's place takes it as a step "
        "(a knock): a mark the print carries or a veil pulls the image's account by what changes or fails samples, "
        "a knock moves the whole image and holds", low=1),
    "tilt_rate": Tunable(
        1e-6, "mm/row/√s", "the camera turning about the optical axis in a second (a clamped mount: µrad)",
        low=0.0),
    "skew_rate": Tunable(
        3e-5, "s/√s",
        "how fast the grating's latch drifts against the exposure in a second (a camera's and a controller's "
        "clocks running apart); at constant speed a latch looks like the camera's place, so a freer latch "
        "blurs the place and the fused position with it", low=0.0),
    "skew_prior": Tunable(
        3e-5, "s", "how far the grating's latch may be from mid-exposure before any frame (a controller's "
        "latch jitter; the model's own latency, when calibration found one, is taken out first): a wider prior "
        "lets the latch take noise for a skew and bias the fused position", low=0.0),
    "clock_drift_prior": Tunable(
        1e-4, "s/s",
        "how far apart the camera's and the controller's clocks run, as a prior (a free-running camera's crystal and "
        "a controller's, each within ±50–100 ppm over temperature and age: 100 ppm apart is a 1σ pair): with the "
        "grating fused the latch drifts at that rate for hours, which a random walk of the latch alone lags behind "
        "(the lens's lever then took the lag as a slide); a wider prior lets the fused position follow the latch's "
        "noise; none where a recording says the controller triggers the camera",
        low=0.0),
    "clock_drift_rate": Tunable(
        1e-6, "s/s/√s", "how fast the clocks' rates apart change in a second (a crystal warming: a few ppm over "
        "minutes)", low=0.0),
    "lever_prior": Tunable(
        300.0, "px",
        "how far the optical axis may be from the ROI's centre along the line (a camera's ROI is rarely centred "
        "on the lens): a magnification change slides the image by this lever times the change", low=0.0),
    "check_window": Tunable(
        25, "frames",
        "read and checked, the last frames whose mean disagreement of camera and grating is tested beside each "
        "frame's own (at the same false-alarm rate): an image sliding against the carriage by less than a bound a "
        "frame (a lens warming, a print growing) shows in their mean while single frames pass; longer, a slow drift "
        "shows sooner in the mean but a step is flagged later", low=1),
    "check_persist_least": Tunable(
        0.25, "1",
        "of a frame's stated variance against the grating, the least taken to persist over the window whatever "
        "calibration measured: calibration measures on the frames its model was fitted to, where the model's error "
        "along the stroke shows less than on a run's (a clean paper rig's run stood 2 µm off the grating over 1.5 mm, "
        "1.3 bounds a frame, where its calibration measured none to persist)", low=0.0, high=1.0),
    "grating_sigma": Tunable(
        0.15e-3, "mm",
        "the grating reading's error against the stage at the exposure: a 0.5 µm step's quantisation "
        "(0.14 µm) and a little cyclic error", low=1e-9),
    "jump_light": Tunable(
        0.5, "1 (relative)",
        "what the light may jump by in one frame (a lamp switched, a shutter); the offset jumps by this share of "
        "the mean gray", low=0.0),
    "jump_field": Tunable(
        0.02, "1 (relative)",
        "what the light's shape across the line (its tilt and bow) may jump by in one frame (a lamp moved, a "
        "shadow's soft edge); small, for the shape is read with the position over less than a period", low=0.0),
    "jump_focus": Tunable(1.0, "px²", "what the blur variance may jump by in one frame (a focus ring touched)",
                          low=0.0),
    "jump_stretch": Tunable(
        2e-3, "1", "what the magnification may move by between frames when the lens is warming (0.2 %)", low=0.0),
    "jump_place": Tunable(
        0.1, "mm", "what the camera's place may jump by in one frame (a knock on the mount)", low=0.0),
    "jump_turn": Tunable(
        0.01, "rad", "what the camera may turn by in one frame (a knock on the mount)", low=0.0),
    "jump_motion": Tunable(
        0.5, "mm/s",
        "the velocity change the stage may make in one frame beyond its acceleration (a collision, a "
        "servo fault, a dropped burst of frames)", low=0.0),
    "band_acceleration": Tunable(
        500.0, "mm/s²",
        "how fast a band of shadow's speed across the field changes (its edges' common acceleration, white between "
        "frames as the stage's): a cable swinging 20 mm at 1 Hz reaches 800 mm/s²; a band's edges are seen in every "
        "frame it darkens, so the motion need only carry them across the frames between", low=0.0),
    "band_rate_depth": Tunable(
        0.02, "1/√s", "the light a band takes drifting in a second (the lamp behind the cable holding)", low=0.0),
    "band_rate_edge": Tunable(
        0.2, "mm/√s", "each of a band's edges wandering against the other in a second (a cable swinging nearer the "
        "lamp or the print widens its shadow)", low=0.0),
    "band_rate_soft": Tunable(
        0.05, "mm/√s", "a band's penumbra changing in a second (the same cable, the same lamp)", low=0.0),
    "band_rate_haze": Tunable(
        0.2, "gray/√s", "the light a band scatters drifting in a second (a veil thickening)", low=0.0),
    "band_prior_depth": Tunable(
        0.3, "1", "the light a band entering may take, about the depth its search found", low=0.0),
    "band_prior_edge": Tunable(
        0.5, "mm", "how far a band's entering edges may be from where its search found them (a step of its grid)",
        low=0.0),
    "band_prior_speed": Tunable(
        30.0, "mm/s", "a band's speed across the field when it enters (a cable swinging through the lamp's light)",
        low=0.0),
    "band_prior_soft": Tunable(
        0.5, "mm", "how far a band's penumbra may be from the one its search found", low=0.0),
    "band_prior_haze": Tunable(
        1.0, "gray", "how far the light a band entering scatters may be from what its search found", low=0.0),
    "dominance": Tunable(
        2.0, "1 (variance ratio)",
        "a position whose variance is more than this times the frame's own noise floor's is carried by "
        "the state's memory of what the frames cannot see (a knock, a lens without the grating): it is "
        "flagged with the state that carries it, unless a grating read and checked finds it where the image put it",
        low=1.0),
    "core_sigma": Tunable(
        3.5, "σ", "robust weight: full for samples within this many robust σ (the measurement's outlier model)",
        low=1.0),
    "cut_sigma": Tunable(
        7.0, "σ", "robust weight: none beyond this many robust σ (Tukey's taper in between)", low=1.0),
    "max_rejected": Tunable(
        0.25, "1 (share of samples)",
        "a frame with more of its samples set aside is not placed: the rest no longer pins the period",
        low=0.0, high=1.0),
    "map_jump_gain": Tunable(
        1.0, "1 (relative)",
        "what a mark landing on the sensor's side (a speck on the window, a veil) may take of a sample's light in "
        "one frame: all of it (an opaque speck)", low=0.0),
    "map_jump_offset": Tunable(
        0.2, "1 (of the mean gray)",
        "what light a veil may scatter into a sample in one frame, as a share of the mean gray", low=0.0),
    "map_rate_gain": Tunable(
        0.02, "1/√s",
        "how fast a sample's gain drifts in a second once something has landed on it (a veil forming over "
        "seconds, a speck settling); samples nothing landed on are as calibrated", low=0.0),
    "map_rate_offset": Tunable(
        0.2, "gray/√s", "how fast the light scattered into a sample drifts in a second once a veil is on it",
        low=0.0),
    "map_most": Tunable(
        0.5, "1 (share of samples)",
        "the most of the samples a frame still uses that may fail at once and land on the sensor's map: a frame "
        "on which more fail is one the state misplaced (its light, its position), not one more marks landed on",
        low=0.0, high=1.0),
    "map_hold": Tunable(
        0.6, "1 (share of samples)",
        "the most of a frame's samples the sensor's map may hold aside in all: the rest place the frame and test "
        "what lands next; beyond it what keeps failing is more likely a state the frames cannot place (without "
        "the grating, a position the state's memory carries) than more marks",
        low=0.0, high=1.0),
    "map_reach_px": Tunable(
        2.0, "px",
        "how far a mark landing on the window reaches beyond the samples that fail their test: out of focus, its "
        "soft edge is below the test but still moves the position", low=0.0),
    "print_jump": Tunable(
        1.0, "1 (relative)",
        "what a mark landing on the print (dust settling, a smudge) may take of the light at its place in one "
        "frame: all of it (an opaque speck)", low=0.0),
    "print_rate": Tunable(
        0.005, "1/√s",
        "how fast the print's reflectance at a place drifts once something has landed there (dust settling "
        "further, a smudge drying); the print elsewhere is as calibrated", low=0.0),
    "tolerance": Tunable(
        1e-6, "mm", "the last Gauss–Newton step in position below which a frame is converged (1 nm: far below any "
        "bound; the step is taken, and what remains is that step times the contraction, ≪ 1 converged)",
        low=0.0),
    "max_iterations": Tunable(
        8, "1", "Gauss–Newton iterations a frame may take (a converged frame takes 2–3)", low=1),
}


@dataclass(frozen=True)
class EstimatorSettings:
    """Values of :data:`TUNABLES` (their units there); ``replace`` makes a variant."""

    false_alarm: float = TUNABLES["false_alarm"].default
    acceleration: float = TUNABLES["acceleration"].default
    stage_acceleration: float = TUNABLES["stage_acceleration"].default
    stage_settle: float = TUNABLES["stage_settle"].default
    stage_servo: float = TUNABLES["stage_servo"].default
    stage_jitter: float = TUNABLES["stage_jitter"].default
    stage_drift: float = TUNABLES["stage_drift"].default
    gain_rate: float = TUNABLES["gain_rate"].default
    gain_rate_holding: float = TUNABLES["gain_rate_holding"].default
    gain_prior: float = TUNABLES["gain_prior"].default
    offset_rate: float = TUNABLES["offset_rate"].default
    offset_rate_holding: float = TUNABLES["offset_rate_holding"].default
    offset_prior: float = TUNABLES["offset_prior"].default
    light_switch_rate: float = TUNABLES["light_switch_rate"].default
    field_rate: float = TUNABLES["field_rate"].default
    field_prior: float = TUNABLES["field_prior"].default
    field_changed_prior: float = TUNABLES["field_changed_prior"].default
    stretch_changed_prior: float = TUNABLES["stretch_changed_prior"].default
    shape_contest_frames: float = TUNABLES["shape_contest_frames"].default
    sensor_floor_gray: float = TUNABLES["sensor_floor_gray"].default
    sensor_ceiling_gray: float = TUNABLES["sensor_ceiling_gray"].default
    mains_hz: float = TUNABLES["mains_hz"].default
    flicker_prior: float = TUNABLES["flicker_prior"].default
    flicker_rate: float = TUNABLES["flicker_rate"].default
    focus_rate: float = TUNABLES["focus_rate"].default
    focus_prior: float = TUNABLES["focus_prior"].default
    focus_drift_prior: float = TUNABLES["focus_drift_prior"].default
    focus_drift_rate: float = TUNABLES["focus_drift_rate"].default
    stretch_rate: float = TUNABLES["stretch_rate"].default
    stretch_prior: float = TUNABLES["stretch_prior"].default
    stretch_rate_most: float = TUNABLES["stretch_rate_most"].default
    place_rate: float = TUNABLES["place_rate"].default
    place_step_frames: float = TUNABLES["place_step_frames"].default
    tilt_rate: float = TUNABLES["tilt_rate"].default
    skew_rate: float = TUNABLES["skew_rate"].default
    skew_prior: float = TUNABLES["skew_prior"].default
    lever_prior: float = TUNABLES["lever_prior"].default
    clock_drift_prior: float = TUNABLES["clock_drift_prior"].default
    clock_drift_rate: float = TUNABLES["clock_drift_rate"].default
    check_window: float = TUNABLES["check_window"].default
    check_persist_least: float = TUNABLES["check_persist_least"].default
    grating_sigma: float = TUNABLES["grating_sigma"].default
    jump_light: float = TUNABLES["jump_light"].default
    jump_field: float = TUNABLES["jump_field"].default
    jump_focus: float = TUNABLES["jump_focus"].default
    jump_stretch: float = TUNABLES["jump_stretch"].default
    jump_place: float = TUNABLES["jump_place"].default
    jump_turn: float = TUNABLES["jump_turn"].default
    jump_motion: float = TUNABLES["jump_motion"].default
    band_acceleration: float = TUNABLES["band_acceleration"].default
    band_rate_depth: float = TUNABLES["band_rate_depth"].default
    band_rate_edge: float = TUNABLES["band_rate_edge"].default
    band_rate_soft: float = TUNABLES["band_rate_soft"].default
    band_rate_haze: float = TUNABLES["band_rate_haze"].default
    band_prior_depth: float = TUNABLES["band_prior_depth"].default
    band_prior_edge: float = TUNABLES["band_prior_edge"].default
    band_prior_speed: float = TUNABLES["band_prior_speed"].default
    band_prior_soft: float = TUNABLES["band_prior_soft"].default
    band_prior_haze: float = TUNABLES["band_prior_haze"].default
    dominance: float = TUNABLES["dominance"].default
    core_sigma: float = TUNABLES["core_sigma"].default
    cut_sigma: float = TUNABLES["cut_sigma"].default
    max_rejected: float = TUNABLES["max_rejected"].default
    map_jump_gain: float = TUNABLES["map_jump_gain"].default
    map_jump_offset: float = TUNABLES["map_jump_offset"].default
    map_rate_gain: float = TUNABLES["map_rate_gain"].default
    map_rate_offset: float = TUNABLES["map_rate_offset"].default
    map_most: float = TUNABLES["map_most"].default
    map_hold: float = TUNABLES["map_hold"].default
    map_reach_px: float = TUNABLES["map_reach_px"].default
    print_jump: float = TUNABLES["print_jump"].default
    print_rate: float = TUNABLES["print_rate"].default
    tolerance: float = TUNABLES["tolerance"].default
    max_iterations: float = TUNABLES["max_iterations"].default

    def __post_init__(self) -> None:
        for name, tunable in TUNABLES.items():
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and tunable.low <= value <= tunable.high):
                raise ValueError(f"estimator setting {name} = {value!r} {tunable.unit}: must be within "
                                 f"[{tunable.low:g}, {tunable.high:g}] ({tunable.reason})")
        if self.cut_sigma <= self.core_sigma:
            raise ValueError(f"estimator setting cut_sigma ({self.cut_sigma:g}) must exceed core_sigma "
                             f"({self.core_sigma:g})")

    def replace(self, **changes: Any) -> "EstimatorSettings":
        unknown = set(changes) - set(TUNABLES)
        if unknown:
            raise ValueError(f"unknown estimator setting {sorted(unknown)[0]!r}; known: {', '.join(TUNABLES)}")
        return dataclasses.replace(self, **changes)

    def for_recording(self, meta: dict[str, Any]) -> "EstimatorSettings":
        """These settings with what a recording's metadata states of its rig: the stage's acceleration, a camera
        triggered by the stage controller (one clock for the exposures and the grating's latch: none runs apart),
        the mains its lamp runs on (0: on DC, no flicker) and the range its camera reads out."""
        from graytrack.core.calibration_data import sensor_range
        from graytrack.core.recording import CAMERA_TRIGGER, MAINS_HZ, STAGE_ACCELERATION

        def number(key: str) -> float | None:
            value = meta.get(key)
            if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
                return float(value)
            return None

        settings = self
        acceleration, mains = number(STAGE_ACCELERATION), number(MAINS_HZ)
        if acceleration is not None and acceleration > 0:
            settings = settings.replace(stage_acceleration=acceleration)
        if mains is not None and mains >= 0:
            settings = settings.replace(mains_hz=mains)
        limits = sensor_range(meta)
        if limits is not None:
            settings = settings.replace(sensor_floor_gray=limits[0], sensor_ceiling_gray=limits[1])
        if meta.get(CAMERA_TRIGGER) == "hardware":
            # (the latch's walk stays: at a steady speed it is the image's offset against the grating walking, and
            # stands for what the frames cannot tell from a latch there, a latency no calibration measured and the
            # model's error along the stroke; held, the latch takes them as a constant the fused bound no longer
            # carries)
            settings = settings.replace(clock_drift_prior=0.0)
        return settings

    def describe(self) -> dict[str, dict[str, Any]]:
        """Every tunable: its value, unit, default and reason."""
        return {name: {"value": getattr(self, name), "unit": tunable.unit, "default": tunable.default,
                       "reason": tunable.reason} for name, tunable in TUNABLES.items()}
