"""The effects a model can carry, each one registered object in its own module of this package.

An effect bundles everything graytrack needs to know about one physical cause:
- ``probe(stage)``: the closed loop's test for it on a fitted stage (one signature for all);
- ``grow(spec, argument)``: what it adds to a :class:`~graytrack.core.structure.ModelSpec`;
- ``prepare_data`` / ``fit_step`` / ``finish``: how calibration handles it (a data correction, a
  step of the alternation around the smooth model, what the fitted model keeps);
- ``frame_part``: what it puts into the tables every tracked frame is solved with
  (:data:`graytrack.core.frame_tables.FRAME_PARTS`); an effect that names none is refused by
  the registry's test, so no model ever leaves the fast path.

Modules are found by name (every public module here that defines ``EFFECT``), so adding an
effect is adding one module: nothing else lists effects. Discovery is lazy because effect modules
use the fitting and diagnosis code that itself asks the registry.
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from graytrack.core.calibration_data import CalibrationData
    from graytrack.core.evidence import Evidence
    from graytrack.core.diagnosis.heldout import LoopModel
    from graytrack.core.models.fourier import FourierModel
    from graytrack.core.structure import ModelSpec


@dataclass
class Alternation:
    """What the rounds of a calibration share: the frames peeled layer by layer, and the layers.

    Y = frame_gain·(pixel_gain·(S + δ·B)·map_factor + pixel_offset) + frame_offset; each bilinear
    effect re-fits its own layer from the others in turn, the smooth model S is fitted to ``lit``
    (δ·B: a change of focus per frame times the blur direction ∂S/∂δ, when the focus effect is on).
    """

    x_mm: "np.ndarray"
    raw: "np.ndarray"  # (K, Rm, n) frames in the model's row layout
    weights: "np.ndarray"  # (K, Rm, n)
    model: "FourierModel"
    frame_gain: "np.ndarray"
    frame_offset: "np.ndarray"
    pixel_gain: "np.ndarray"
    pixel_offset: "np.ndarray"
    map_factor: "np.ndarray | float" = 1.0
    smooth: "np.ndarray | None" = None
    found: dict[str, Any] | None = None  # model fields the steps found (flat field, target map, …)
    blurred: "np.ndarray | float" = 0.0  # δ·B per frame and pixel (the focus effect's layer)

    @property
    def per_frame(self) -> "np.ndarray":
        """Frames with the per-frame common mode taken out."""
        return (self.raw - self.frame_offset[:, None, None]) / self.frame_gain[:, None, None]

    @property
    def lit(self) -> "np.ndarray":
        """The light on the target as the smooth model sees it (common mode, flat field and the
        frames' change of focus out)."""
        return (self.per_frame - self.pixel_offset) / self.pixel_gain - self.blurred * self.map_factor

    @property
    def shaded(self) -> "np.ndarray":
        """The model's light before the per-frame and per-pixel layers: asked for once S is fitted."""
        smooth = self.smooth
        if smooth is None:
            raise ValueError("the smooth model S is fitted before the layers are shaded")
        return (smooth + self.blurred) * self.map_factor


class Effect:
    """Base of every effect: the defaults say "this effect does nothing at that stage"."""

    name: str = ""
    family: str = ""  # the physical causes that leave this structure
    adds: str = ""  # what the model gains
    fitted: str = ""  # how the addition is fitted
    order: int = 100  # position in the alternation and among data-quality findings
    data_quality: bool = False  # a finding about the data: tried before model terms
    bilinear: bool = False  # fitted by alternation with the smooth model (switched off for geometry fits)
    search_pitch: bool = False  # growing it needs α·d to a fraction of a defect: search it again
    refits_geometry: bool = False  # its layer, unknown in the first round, would pull τ_w: refine it again after
    frame_part: str = ""  # its entry in core/frame_tables.FRAME_PARTS: how tracking holds what it adds

    def describe(self) -> dict[str, str]:
        return {"effect": self.name, "family": self.family, "adds": self.adds, "fitted": self.fitted}

    # ----------------------------------------------------------------- closed loop
    def probe(self, stage: "LoopModel") -> "Evidence | None":
        """Evidence for this effect in a stage's residual (None: nothing to say)."""
        return None

    def grow(self, spec: "ModelSpec", argument: Any) -> "ModelSpec | None":
        """The spec with this effect added or grown; None when it cannot grow any further."""
        return None if spec.get(self.name) is not None else spec.set(self.name, True if argument is None else argument)

    def screen(self, data: "CalibrationData") -> Any:
        """A setting found without any model (a data-quality check every calibration runs, the
        named model kinds included); None: nothing found or not a model-free effect."""
        return None

    # ----------------------------------------------------------------- calibration
    def model_fields(self, setting: Any) -> dict[str, Any]:
        """Fields of the model template this setting fixes before fitting."""
        return {}

    def prepare_data(self, setting: Any, data: "CalibrationData") -> "CalibrationData":
        """A correction of the calibration data (reference instant, unusable samples)."""
        return data

    def fit_step(self, setting: Any, state: Alternation) -> None:
        """One round of this effect's part of the alternation (bilinear effects only)."""

    def finish(self, setting: Any, state: Alternation, model: "FourierModel") -> "FourierModel":
        """The fitted model with what this effect keeps in it."""
        return model

    def report(self, setting: Any) -> Any:
        """What report.json lists for this setting beyond the step (e.g. the pixels masked); None: nothing."""
        return None


_REGISTRY: dict[str, Effect] = {}


def registry() -> dict[str, Effect]:
    """Every effect, by name, in ``order``."""
    if not _REGISTRY:
        found = []
        for info in pkgutil.iter_modules(__path__):
            if info.name.startswith("_"):
                continue
            module = importlib.import_module(f"{__name__}.{info.name}")
            effect = getattr(module, "EFFECT", None)
            if isinstance(effect, Effect):
                found.append(effect)
        for effect in sorted(found, key=lambda e: (e.order, e.name)):
            if effect.name in _REGISTRY:
                raise RuntimeError(f"effect {effect.name!r} registered twice")
            _REGISTRY[effect.name] = effect
    return _REGISTRY


def active(spec: "ModelSpec") -> list[tuple[Effect, Any]]:
    """The effects a spec switches on, with their settings, in ``order``."""
    return [(effect, spec.get(name)) for name, effect in registry().items() if spec.get(name) is not None]


def prepare_data(spec: "ModelSpec", data: "CalibrationData") -> "CalibrationData":
    """Calibration data corrected by every effect of ``spec`` (apply once per data set)."""
    for effect, setting in active(spec):
        data = effect.prepare_data(setting, data)
    return data


def screened(spec: "ModelSpec", data: "CalibrationData") -> "ModelSpec":
    """``spec`` with every model-free data-quality finding on ``data`` added."""
    for effect in registry().values():
        setting = effect.screen(data)
        if setting is not None:
            spec = effect.grow(spec, setting) or spec
    return spec

