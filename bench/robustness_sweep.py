"""Calibrate on one run of a virtual rig, measure another: the error against the noise floor.

Each case is a rig with effects nobody tells the software about; the measured run is a second
session of the same rig (same fixed patterns, its own noise), sometimes with the light changed or
a pixel failed in between. For each case it prints, for the seed paper's model (`calibrate
--model paper`) and for the closed loop's model (`diagnose`), the frames lost and the error std
over the rms of the per-frame Cramér–Rao bounds, tracked as `graytrack track` does, and how many
of the run's frames were flagged stale (the model no longer describes the images, or the camera no
longer agrees with the grating). Every model is also tracked with ``--trim`` and with
``--no-reference`` (bench/truth_score.py), and every frame scored against the rig's truth, not the
grating: the placed frames more than ``FAR_PULL`` of their own bounds off and those of them left
unflagged (a change that comes into view mid-run is an episode, which a run's share of flagged
frames hides), and what the run learned (texture marks, focus frames, trims; a steady run: none).
The last lines list the runs that break issue #40's acceptance (:func:`breaks`). A case whose
change comes while the stage stands still (``at_rest=1``) measures a step-and-settle run
(:func:`measured_motion`); every other case the scenario's sweep.

    .venv/bin/python bench/robustness_sweep.py [CASE-SUBSTRING ...]   (a case runs when its line has any)
"""

from __future__ import annotations

import sys
import time

from graytrack.core.calibration import calibrate
from graytrack.core.diagnosis import diagnose
from graytrack.drivers.sim.scenarios import build_rig
from graytrack.drivers.sim.stage import steps
from truth_score import FAR_PULL, MODES, Score, scored

LATER_LIGHT = "light_change:gain=0.85:ambient_gray=8:start_s=2"
LATER_PIXEL = "bad_pixels:stuck=1:dead=0:hot=0:row=0:pixel=40:start_s=2.5"
LATER_GROWTH = "target_growth:ppm=250"  # the paper print grew (humidity) between calibration and the run
LATER_FOCUS = "focus_drift:px=0.5"  # the blur σ grows by half a pixel after calibration (a lens mount warming up)
LATER_SHARPER = "focus_drift:px=-0.5"
LATER_MAGNIFICATION = "magnification_drift:ppm=1500:ramp_s=10"  # the lens warming up: 0.15 % over the run
LATER_CYCLE = "magnification_drift:ppm=1500:cycle_s=6"  # a temperature cycle: the magnification comes and goes
LATER_FOCUS_RAMP = "focus_drift:px=1:ramp_s=10"  # the blur σ 1.6 → 2.6 px over the run (bench/focus_drift.py)
LATER_FOCUS_CYCLE = "focus_cycle:px=1.5:period_s=6"  # ... out by 1.5 px and back within 6 s (warming and cooling)
LATER_SMUDGE = "smudge:depth=0.35"  # a smudge on the print after calibration (a finger), coming into view mid-run
LATER_SHADOW = "moving_shadow:passes=2:period_s=4:start_s=2"  # a cable's shadow swinging across the field, twice
LATER_DUST = "dust_settling"  # 30 specks landing on the print one by one during the run (learned: core/texture.py)
LATER_WINDOW = "window_dust"  # 6 specks landing on the camera's window during the run: fixed to the pixels
LATER_WINDOW_REST = "window_dust:at_rest=1"  # ... each while the stage stands still: a print mark until it moves
LATER_VEIL = "veil"  # a veil forming on the window from 2 s: 25 % of the light and 3 gray scattered over 40 % of it
LATER_KNOCK = "knock:um=40:deg=0.2:at_s=2"  # the camera knocked on its mount at 2 s: 40 µm along the axis, 0.2°
LATER_VIGNETTING = "vignetting_change"  # the vignetting 5 % deeper at the sensor's edge from 2 s (an aperture knocked)
REST_STEPS = 10  # an at-rest case's measured run: the stroke in this many steps ...
REST_DWELL = 0.06  # ... each followed by a rest of this share of the run (0.6 s of 10 s: 30 frames at 50 frames/s)

SECONDS = {"lab": 6.0}  # the lab rig runs at 200 frames/s with 16 × 128 pixels

# (scenario, effects of the rig, what changes before the measured run)
CASES = [
    ("paper", "", ""),
    ("paper", "", LATER_LIGHT),
    ("paper", "", LATER_PIXEL),
    ("paper", "defocus:sigma_um=200", ""),
    ("paper", "distortion:k1=0.02,vignetting:edge=0.15", ""),
    ("paper", "print_gamma:gamma=1.4,harmonics:h2=0.05:h3=0.02", LATER_LIGHT),
    ("paper", "prnu:sigma=0.03,dsnu:sigma=2", ""),
    ("paper", "scratches:count=3", ""),
    ("paper", "dust:count=6", LATER_LIGHT),
    ("paper", "flicker:mains_hz=50:depth=0.05", ""),
    ("paper", "quantize:bits=6", ""),
    ("paper", "photon_transfer:full_well=10000:read_e=8:bits=8", LATER_LIGHT),
    ("paper", "bad_pixels:stuck=1:dead=1:hot=1:noisy=1", ""),
    ("paper", "saturation:gain=1.3,quantize:bits=8", ""),
    ("paper", "pitch_scale:ppm=500,gradient:per_10mm=0.08", ""),
    ("paper", "motion_blur:exposure_ms=8", ""),
    ("paper", "dropped_frames:p=0.1,timestamp_jitter:us=300", ""),
    ("strip16", "tilt:deg=2,prnu:sigma=0.01,bad_pixels", LATER_LIGHT + "," + LATER_PIXEL.replace("row=0", "row=3")),
    ("lab", "", LATER_LIGHT),
    ("paper", "glare:gray=20", ""),
    ("paper", "gain_hunting:depth=0.05", ""),
    ("paper", "telegraph_pixels:count=3", ""),
    ("paper", "row_banding:gray=1", ""),
    ("paper", "mono12_in_16:black_gray=16", LATER_LIGHT),
    ("paper", "smudge:depth=0.35", ""),
    ("paper", "vibration:um=2:hz=180", ""),
    ("paper", "duplicate_frames:p=0.03", ""),
    ("paper", "clock_drift:ppm=100", ""),
    ("strip16", "row_banding:gray=1,telegraph_pixels:count=6", ""),
    ("lab", "gain_hunting:depth=0.05,duplicate_frames:p=0.03", ""),
    ("lab", "mjpeg:quality=75", ""),
    ("strip16", "mjpeg:quality=75", ""),
    ("strip16", "defocus:sigma_um=100,mjpeg:quality=75", LATER_FOCUS_RAMP),  # a blur still found through the stream
    ("paper", "", LATER_GROWTH),
    ("strip16", "", LATER_GROWTH),
    ("paper", "glints:p=0.05", "glints:p=0.15"),  # the later spec replaces the rate: 5 % → 15 % of frames
    ("strip16", "glints:p=0.05", "glints:p=0.15"),
    ("paper", "defocus:sigma_um=200", LATER_FOCUS),
    ("paper", "defocus:sigma_um=200", LATER_SHARPER),
    ("strip16", "defocus:sigma_um=200", LATER_FOCUS),
    ("strip16", "defocus:sigma_um=200", LATER_SHARPER),
    ("paper", "", LATER_SMUDGE),
    ("paper", "", LATER_SHADOW),
    ("paper", "", LATER_DUST),
    ("paper", "", LATER_MAGNIFICATION),
    ("strip16", "", LATER_MAGNIFICATION),
    ("strip16", "", LATER_CYCLE),
    ("paper", "defocus:sigma_um=100", LATER_FOCUS_RAMP),
    ("strip16", "defocus:sigma_um=100", LATER_FOCUS_RAMP),
    ("paper", "defocus:sigma_um=100", LATER_FOCUS_CYCLE),
    ("strip16", "defocus:sigma_um=100", LATER_FOCUS_CYCLE),
    # a lab strip with most of what the issues named at once (12 bits, vibration, PRNU, a gradient,
    # glints), the focus drifting and the glints more frequent in the measured run
    ("lab", "photon_transfer:full_well=20000:read_e=6:bits=12:black_gray=4,vibration:um=1:hz=120,prnu:sigma=0.01,"
            "gradient:per_10mm=0.05,glints:p=0.05", "glints:p=0.15,focus_drift:px=0.5:start_s=0.5"),
    ("paper", "", LATER_WINDOW),
    ("strip16", "", LATER_WINDOW),
    ("paper", "", LATER_WINDOW_REST),
    ("strip16", "", LATER_WINDOW_REST),
    ("paper", "", LATER_VEIL),
    ("strip16", "", LATER_VEIL),
    ("paper", "", LATER_VIGNETTING),
    ("strip16", "", LATER_VIGNETTING),
    ("paper", "", LATER_KNOCK),
    ("strip16", "", LATER_KNOCK),
]


STEADY_FLAGGED = 0.01  # a steady run (nothing changed since calibration): fewer of its frames flagged, nothing learned
SILENT_SHARE = 0.005  # on every run, trim on or off, grating read or not: at most this share of the placed frames
# FAR_PULL bounds off the truth without a flag
DUST_RATIO, DUST_LOST = 1.3, 0.01  # dust settling: within this of the clean print's bound, at most this share lost
FOCUS_RATIO, FOCUS_FLAGGED = 1.3, 0.9  # focus drift: measured within this, or flagged on this share of the frames
HELD, OFF = 1.2, 2.0  # within HELD of its bound: held (the model describes the rig); beyond OFF: off (and flagged)


def breaks(score: Score, later: str, clean_bound_um: float) -> list[str]:
    """What of issue #40's acceptance the run breaks (empty: none). A steady run is judged where its
    model describes the rig (within ``HELD`` of its bound): the seed model on a rig it lacks a
    layer for is rightly flagged, and the print's marks it lacks (scratches) are rightly learned.
    (A run beyond ``OFF`` of its bound flagged on most of its frames is :func:`never_silently_wrong`'s,
    over all its frames: a run whose wrong frames are flagged one by one passes here.)"""
    out = []
    if score.silent_share > SILENT_SHARE:
        out.append(f"{100 * score.silent_share:.2f} % unflagged {FAR_PULL:g}+ bounds off")
    flagged = score.flagged / score.frames
    if not later and score.ratio <= HELD and (flagged >= STEADY_FLAGGED or score.learned != "-"):
        out.append(f"steady: {100 * flagged:.1f} % flagged, learned {score.learned}")
    dusty = score.std_um / clean_bound_um > DUST_RATIO or score.lost > DUST_LOST * score.frames
    if "dust_settling" in later and dusty:
        out.append(f"dust: {score.std_um / clean_bound_um:.2f}x the clean bound, {score.lost} lost")
    if ("focus_drift" in later or "focus_cycle" in later) and score.ratio > FOCUS_RATIO and flagged < FOCUS_FLAGGED:
        out.append(f"focus: {score.ratio:.2f}x with {100 * flagged:.0f} % flagged")
    return out


def measured_motion(rig, later: str, seconds: float):
    """The measured run's trajectory: step-and-settle over the stroke when the change comes at rest
    (the sweep never stands still), else None (the scenario's sweep)."""
    if "at_rest=1" not in later:
        return None
    start, end = rig.config.stroke_mm
    return steps(start, end, REST_STEPS, REST_DWELL * seconds, rig.config.stage)


def main(*selections: str) -> None:
    verdicts: list[tuple[float, float, bool]] = []  # (error / bound, share flagged, nothing changed) per run
    far_frames = [0, 0, 0]  # over the sweep: placed frames, beyond FAR_PULL bounds off the truth, those not flagged
    broken: list[str] = []
    rigs: dict[tuple[str, str], tuple] = {}  # (scenario, rig effects): the rig's models (calibrated once)
    clean: dict[tuple[str, str, str], float] = {}  # (scenario, model, mode): the clean print's bound, µm
    print(f"{'scenario':9} {'rig effects':52} {'changed':12} {'paper: lost  std/bound  stale':>30} "
          f"{'loop: lost  std/bound  stale':>30}  loop added; then each model and mode against the truth")
    for scenario, rig_effects, later in CASES:
        label = f"{scenario} {rig_effects} {later}"
        if selections and not any(selection in label for selection in selections):
            continue
        started = time.perf_counter()
        seconds = SECONDS.get(scenario, 20.0)  # 1,000 frames at the paper rig's 50 frames/s
        if (scenario, rig_effects) not in rigs:
            calibration, _ = build_rig(scenario, rig_effects, seed=3).record(seconds)
            loop = diagnose(calibration)
            rigs[scenario, rig_effects] = (calibrate(calibration, "paper").model, loop.final_model, loop)
        paper_model, loop_model, loop = rigs[scenario, rig_effects]
        run_effects = ",".join(part for part in (rig_effects, later) if part)
        measured = build_rig(scenario, run_effects, seed=3, run=1)
        run, truth = measured.record(seconds / 2, measured_motion(measured, later, seconds / 2))
        cells, lines = [], []
        for name, model in (("paper", paper_model), ("loop", loop_model)):
            for mode, options in MODES.items():
                score = scored(model, run, truth, **options)
                if not later and not rig_effects:
                    clean[scenario, name, mode] = score.bound_um
                why = breaks(score, later, clean.get((scenario, name, mode), score.bound_um))
                lines.append(f"    {name:5} {mode:14} {score.cell()}" + (f"  BREAKS: {'; '.join(why)}" if why else ""))
                if why:
                    broken.append(f"{label.strip()} | {name} {mode}: {'; '.join(why)}")
                far_frames[0] += score.placed
                far_frames[1] += score.far
                far_frames[2] += score.silent
                if mode == "grating":
                    cells.append(f"{score.lost:5d} {score.std_um:6.3f}/{score.bound_um:.3f}={score.ratio:4.2f} "
                                 f"{score.flagged:5d}")
                    verdicts.append((score.ratio, score.flagged / run.n_frames, not later))
        added = ",".join(step.effect for step in loop.steps) or "-"
        repeated = score.repeated
        added += f", {repeated} repeated images set aside" if repeated else ""
        changed = " ".join(word for word, key in (("light", "light_change"), ("pixel", "start_s=2.5"),
                                                       ("growth", "target_growth"), ("glints", "glints"),
                                                       ("blur+0.5px", "px=0.5"), ("blur-0.5px", "px=-0.5"),
                                                       ("smudge", "smudge"), ("shadow", "moving_shadow"),
                                                       ("dust", "dust_settling"),
                                                       ("magnif.", "magnification"),
                                                       ("blur ramp", "focus_drift:px=1:ramp_s"),
                                                       ("blur cycle", "focus_cycle"), ("window", "window_dust"),
                                                       ("at rest", "at_rest=1"), ("veil", "veil"),
                                                       ("vignet.", "vignetting_change"))
                           if key in later)
        print(f"{scenario:9} {rig_effects or '-':52.52} {changed or '-':12}"
              f" {cells[0]:>30} {cells[1]:>30}  {added} ({time.perf_counter() - started:.0f} s)", flush=True)
        print("\n".join(lines), flush=True)
    print(never_silently_wrong(verdicts))
    share = 100 * far_frames[2] / max(far_frames[0], 1)
    print(f"placed frames (every model and mode) more than {FAR_PULL:g} of their own bounds off the truth: "
          f"{far_frames[1]} of {far_frames[0]}, not flagged: {far_frames[2]} ({share:.3f} %)")
    print(f"runs breaking issue #40's acceptance: {len(broken)}" + "".join(f"\n    {line}" for line in broken))


def never_silently_wrong(verdicts: list[tuple[float, float, bool]]) -> str:
    """The validity monitor's acceptance over the sweep: every run off by more than twice its bound
    flagged on ≥ 90 % of its frames; every steady run (nothing changed since calibration) at its
    bound (≤ 1.2×) flagged on < 1 %. A run whose rig changed may be flagged at its bound: the
    change is what the flag says (a focus that moved, a lamp at 40 %)."""
    off = [flagged for ratio, flagged, _ in verdicts if ratio > OFF]
    held = [flagged for ratio, flagged, steady in verdicts if ratio <= HELD and steady]
    return (f"runs beyond 2x their bound: {len(off)}, flagged on >= 90 % of frames: {sum(f >= 0.9 for f in off)}; "
            f"steady runs within 1.2x: {len(held)}, flagged on < 1 %: {sum(f < 0.01 for f in held)}")


if __name__ == "__main__":
    main(*sys.argv[1:])
