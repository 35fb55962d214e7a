"""The closed loop: fit the seed paper's model, probe its held-out residual, add the effect the
strongest structure points to, keep it only if held-out figures improve beyond chance, repeat.

Nothing here knows which effects a recording contains: the probes look along every axis where
a physical effect can live, and an effect stays only when frames the fit never saw agree. The
geometry (τ_w, α·d) is fitted once, with the seed paper's model, and then held: later terms
could trade against it without improving anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from graytrack.core.calibration import KIND_SPECS
from graytrack.core.calibration_line import record_calibration_line
from graytrack.core.calibration_data import CalibrationData
from graytrack.core.compression import JpegFinding, bound_with_quantisation_mm, find_jpeg
from graytrack.core.geometry import initial_geometry
from graytrack.core.geometry_check import GeometryCheck, check_geometry, raise_if_refused
from graytrack.core.jsonable import finite_or_none
from graytrack.core import effects
from graytrack.core.structure import ModelSpec, fit_spec, fit_spec_pitch_search
from graytrack.core.evidence import Evidence
from graytrack.core.diagnosis.heldout import Figures, LoopModel, figures, fit_on, loop_split
from graytrack.core.adequacy import assessed
from graytrack.core.models.fourier import FourierModel
from graytrack.core.noise import pooled_bound, reference_resolution_mm
from graytrack.core.recording import Recording

Progress = Callable[[float, str], None]
MAX_STEPS = 8
CANDIDATES_PER_STEP = 3
CONTENDERS_PER_STEP = 2  # effects that pass the held-out test, compared before one is kept
MIN_Z = 5.0  # evidence weaker than this many noise standard deviations is noise
NOISE_FLOOR_MARGIN = 1.1  # error std within this factor of the bound: nothing left worth chasing
MAJOR_RESIDUAL_GAIN = 0.5  # a structure removing this share of the held-out residual power is no fluke
_NO_TRANSIENTS = {"count": 0, "frames": 0, "samples": 0, "share_of_frames": 0.0, "events": []}


@dataclass
class Step:
    effect: str
    evidence: Evidence
    stage: LoopModel
    accepted: bool
    reason: str

    def as_dict(self) -> dict[str, Any]:
        figures = self.stage.figures.as_dict()
        return {"effect": self.effect, "family": effects.registry()[self.effect].family, "evidence": self.evidence.text,
                "z": round(float(self.evidence.z), 2), **{key: figures[key] for key in
                                                          ("rmse_gray", "error_std_um", "error_max_um", "lost_frames")},
                "model": figures["model"], "decision": self.reason}


@dataclass
class DiagnosisResult:
    before: LoopModel
    after: LoopModel
    steps: list[Step]
    rejected: list[Step]
    final_model: FourierModel
    sigma_gray: float
    holdout: str
    reference_step_mm: float = 0.0  # quantisation of the grating readout the errors are measured against
    remaining: list[Evidence] = field(default_factory=list)
    compression: JpegFinding | None = None  # the frames come from a JPEG (MJPEG) stream
    geometry: GeometryCheck | None = None  # the rig's set-up judged on the seed paper's fit, then the final one

    def compression_report(self) -> dict[str, Any] | None:
        """The JPEG stream the frames came through and the bound its quantisation leaves (the
        white-noise bound promises more than such frames hold), on the held-out frames."""
        if self.compression is None:
            return None
        fit = self.after.val
        slope = np.broadcast_to(fit.slope, fit.data.frames.shape) * fit.usable
        bound_mm = bound_with_quantisation_mm(slope, fit.data.sigma_gray**2, self.compression.table)
        return {"kind": "jpeg", "quality": self.compression.quality, "score": round(self.compression.score, 3),
                "crlb_um": round(pooled_bound(bound_mm) * 1e3, 4)}

    @property
    def refused(self) -> bool:
        """The loop stopped at a fault of the rig's geometry: no model of it is worth keeping."""
        return self.geometry is not None and self.geometry.refused

    def raise_if_refused(self) -> None:
        raise_if_refused(self.geometry)

    def report(self) -> dict[str, Any]:
        """report.json (docs/contracts.md contract, with extra keys that explain the decisions). A figure that
        does not exist (no frame placed, no bound) is null, never NaN: JSON carries no NaN."""
        return finite_or_none({
            "geometry": None if self.geometry is None else self.geometry.as_dict(),
            "noise": {"gray": round(float(self.sigma_gray), 5), "crlb_um": self.after.figures.as_dict()["crlb_um"],
                      "crlb_before_um": self.before.figures.as_dict()["crlb_um"],
                      "reference_resolution_um": round(self.reference_step_mm * 1e3, 4),
                      "floor_um": round(float(np.hypot(self.after.figures.crlb_um,
                                                       self.reference_step_mm * 1e3 / np.sqrt(12.0))), 4),
                      "pixel_noise": _curve(self.final_model)},
            "before": self.before.figures.as_dict(),
            "steps": [step.as_dict() for step in self.steps],
            "after": self.after.figures.as_dict(),
            "rejected": [step.as_dict() for step in self.rejected],
            "remaining_evidence": [ev.as_dict() for ev in self.remaining[:5]],
            "heldout": self.holdout,
            "final_model": self.final_model.describe(),
            "effects": {name: effect.describe() for name, effect in effects.registry().items()},
            "findings": {**{effect.name: entry for effect, setting in effects.active(self.after.spec)
                            if (entry := effect.report(setting)) is not None},
                         "transients": self.final_model.info.get("transients") or _NO_TRANSIENTS,
                         **({"compression": compressed} if (compressed := self.compression_report()) else {})},
        })


def _curve(model: FourierModel) -> dict[str, Any]:
    """The noise model behind the bound: the fitted photon-transfer curve, or one σ for all."""
    noise = model.noise()
    body: dict[str, Any] = {key: round(value, 6) for key, value in noise.as_dict().items()}
    body["signal_dependent"] = noise.signal_dependent
    chi2 = model.info.get("calibration_chi2")
    body["calibration_chi2"] = None if chi2 is None else round(float(chi2), 4)
    return body


def _stage(spec: ModelSpec, train: CalibrationData, val: CalibrationData, geometry: tuple[float, float, float],
           refine_geometry: bool = False, search_pitch: bool = False,
           searched: dict[str, float] | None = None) -> LoopModel:
    """The model of structure ``spec`` fitted on ``train``, with its figures on ``val``. With
    ``search_pitch``, α·d is searched, near the one the loop's last search found (``searched``, updated)."""
    train, val = effects.prepare_data(spec, train), effects.prepare_data(spec, val)
    if search_pitch:
        searched = {} if searched is None else searched
        model = fit_spec_pitch_search(spec, train, *geometry, found_mm=searched.get("pitch")).model
        searched["pitch"] = model.pixel_pitch_mm
    else:
        model = fit_spec(spec, train, *geometry, refine_geometry=refine_geometry).model
    train_fit, val_fit = fit_on(model, train), fit_on(model, val)
    return LoopModel(spec, model, train_fit, val_fit, figures(model, val, val_fit))


def _better(new: Figures, old: Figures, n_samples: int) -> tuple[bool, str]:
    """Keep an effect only when held-out figures improve by more than their sampling noise.

    The residual is measured on every held-out sample, the error std on one number a frame: a
    few hundred frames give it a standard error of √(1/2n) of itself. A structure that removes a
    large share of the residual (a map a row, of dust the rows see differently: 68 % of the lab
    strip's) may cost the error up to two of those standard errors; a smaller gain only 3 %.
    """
    if not np.isfinite(new.error_max_um) and np.isfinite(old.error_max_um):
        return False, "rejected: the tracker lost frames it held before"
    if not (old.rmse_gray > 0 and old.error_std_um > 0 and np.isfinite(new.rmse_gray)
            and np.isfinite(new.error_std_um)):
        # no scatter to judge a gain against (one held-out frame placed, or none): nothing is kept on it
        return False, (f"rejected: the held-out figures cannot judge it (rmse {old.rmse_gray:.3f} → "
                       f"{new.rmse_gray:.3f} gray, error std {old.error_std_um:.3f} → {new.error_std_um:.3f} µm "
                       f"over {int(np.isfinite(old.error_um).sum())} placed frames)")
    residual_gain = 1.0 - (new.rmse_gray / old.rmse_gray) ** 2
    error_gain = 1.0 - (new.error_std_um / old.error_std_um) ** 2
    chance = 4.0 * np.sqrt(2.0 / n_samples)
    error_noise = 2.0 / np.sqrt(2.0 * max(len(old.error_um), 1))
    allowed = 1.0 + (error_noise if residual_gain > MAJOR_RESIDUAL_GAIN else 0.03)
    figures_text = (f"held-out rmse {old.rmse_gray:.3f} → {new.rmse_gray:.3f} gray, "
                    f"error std {old.error_std_um:.3f} → {new.error_std_um:.3f} µm")
    if residual_gain > chance and new.error_std_um <= allowed * old.error_std_um:
        return True, "kept: " + figures_text
    if error_gain > 0.10 and new.rmse_gray <= 1.01 * old.rmse_gray:
        return True, "kept: " + figures_text
    return False, "rejected: " + figures_text


def _at_noise_floor(stage: LoopModel) -> bool:
    sigma2 = stage.val.data.sigma_gray**2
    n = float(stage.val.usable.sum())
    residual_ok = stage.figures.rmse_gray**2 <= sigma2 * (1.0 + 4.0 * np.sqrt(2.0 / n))
    return residual_ok and stage.figures.error_std_um <= NOISE_FLOOR_MARGIN * stage.figures.crlb_um


def all_evidence(stage: LoopModel) -> list[Evidence]:
    """Every effect's probe on ``stage``: data-quality findings first (in the registry's order),
    then model terms by how much of the held-out residual they explain."""
    found = [(effect, evidence) for effect in effects.registry().values()
             if (evidence := effect.probe(stage)) is not None]
    quality = [evidence for effect, evidence in found if effect.data_quality]
    terms = sorted((evidence for effect, evidence in found if not effect.data_quality),
                   key=lambda ev: ev.explained_gray2, reverse=True)
    return quality + terms


def _candidates(stage: LoopModel) -> list[Evidence]:
    """What the probes found beyond noise: data-quality findings first, then model terms by how
    much of the held-out residual they explain."""
    return [ev for ev in all_evidence(stage) if ev.z > MIN_Z]


def _next_step(current: LoopModel, train: CalibrationData, val: CalibrationData, rejected: list[Step],
               row_shift_guess_mm: float, say: Progress, fraction: float,
               searched: dict[str, float] | None = None) -> Step | None:
    """Try the effects the residual points to; of those that pass the held-out test, the one that
    tracks best (the strongest evidence is not always the right cause: a flexible term can soak
    up what a simpler physical one explains). A fault of the data (bad pixels, clipping, a skewed
    reference) that passes is taken at once. None when nothing passes."""
    contenders: list[Step] = []
    m = current.model
    geometry = (m.period_mm, m.pixel_pitch_mm, m.row_shift_mm or row_shift_guess_mm)
    for evidence in _candidates(current)[:CANDIDATES_PER_STEP]:
        effect = effects.registry()[evidence.effect]
        spec = effect.grow(current.spec, evidence.argument)
        if spec is None:
            continue
        say(fraction, f"trying {evidence.effect}")
        trial = _stage(spec, train, val, geometry, search_pitch=effect.search_pitch, searched=searched)
        keep, reason = _better(trial.figures, current.figures, int(current.val.usable.sum()))
        record = Step(evidence.effect, evidence, trial, keep, reason)
        if not keep:
            rejected.append(record)
            continue
        if effect.data_quality:  # a fault of the data is fixed first, not weighed against model terms
            return record
        contenders.append(record)
        if len(contenders) == CONTENDERS_PER_STEP:
            break
    return min(contenders, key=lambda step: (step.stage.figures.error_std_um, step.stage.figures.rmse_gray),
               default=None)


def diagnose(calibration: Recording, validation: Recording | None = None, progress: Progress | None = None,
             max_steps: int = MAX_STEPS) -> DiagnosisResult:
    """Run the closed loop on a calibration recording (and an optional validation recording)."""
    say = progress or (lambda fraction, label: None)
    data, train, val, holdout = loop_split(calibration, validation)
    say(0.02, "fitting the seed paper's model")
    geometry = initial_geometry(train)
    current = before = _stage(KIND_SPECS["paper"], train, val, geometry, refine_geometry=True)
    steps: list[Step] = []
    rejected: list[Step] = []
    # A fault of the rig's set-up (a reversed pixel axis, a wrong period) is no missing model term:
    # the loop stops rather than bend a degree-9 polynomial and the period around it.
    verdict = check_geometry(train, before.model)
    if verdict.refused:
        say(1.0, f"stopped: {verdict.message}")
        return DiagnosisResult(before, before, [], [], before.model, val.sigma_gray, holdout,
                               readout_step_mm(calibration if validation is None else validation), [],
                               geometry=verdict)
    searched: dict[str, float] = {}  # α·d where the last search found it: a later search starts there
    for step_index in range(max_steps):
        if _at_noise_floor(current):
            break
        say(0.05 + 0.85 * step_index / max_steps, f"step {step_index + 1}: probing the residual")
        accepted = _next_step(current, train, val, rejected, geometry[2], say,
                              0.05 + 0.85 * (step_index + 0.5) / max_steps, searched)
        if accepted is None:
            break
        steps.append(accepted)
        current = accepted.stage
    final_model = current.model
    # the data as the final structure reads it (the grating at the exposure, unusable samples out):
    # what the model is judged on, as it was fitted to it
    corrected = effects.prepare_data(current.spec, data)
    if validation is None:
        say(0.92, "refitting the final structure on all calibration frames")
        m = current.model
        final_model = fit_spec(current.spec, corrected, m.period_mm, m.pixel_pitch_mm, m.row_shift_mm,
                               refine_geometry=False).model
    assessed(final_model, corrected)
    record_calibration_line(final_model, calibration)  # camera against grating: drift is measured from it
    from graytrack.core.estimator.filter import kept_from_calibration  # (the estimator imports what imports this)

    kept_from_calibration(final_model, calibration)  # what the estimator starts from and states (core/calibration.py)
    remaining = _candidates(current)
    if steps:  # the final model's own residual and geometry (the seed model's doubts may be gone)
        verdict = check_geometry(corrected, final_model)
    say(1.0, f"{len(steps)} effect(s) added")
    return DiagnosisResult(before, current, steps, rejected, final_model, val.sigma_gray, holdout,
                           readout_step_mm(calibration if validation is None else validation), remaining,
                           find_jpeg((calibration if validation is None else validation).frames), verdict)


def readout_step_mm(measured_against: Recording) -> float:
    """The grating readout's step, found on the whole recording the held-out errors are measured against.

    Never on the held-out frames alone: of a step-and-settle sweep they keep some stops and drop
    others, and stops 256.5 µm apart with gaps of one and seven stops look like a 256.5 µm
    readout grid. The whole sweep shows one regular stop spacing, which is no readout step.
    """
    return reference_resolution_mm(measured_against.reference)
