"""Model files: JSON with a schema name and version, so a file from another tool or a future
incompatible graytrack is refused by name instead of being half-read."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from graytrack.core.errors import ModelError
from graytrack.core.files import write_atomic
from graytrack.core.models.fourier import FourierModel
from graytrack.core.pixel_noise import PixelNoise

SCHEMA = "graytrack.model"
SCHEMA_VERSION = 1

_SCALAR_FIELDS = ("period_mm", "pixel_pitch_mm", "n_pixels", "harmonics", "pixel_degree", "stroke_degree",
                  "n_rows", "row_degree", "row_shift_mm", "common_mode", "noise_gray", "name",
                  "target_map_origin_mm", "target_map_step_mm")
_ARRAY_FIELDS = ("coeffs", "pixel_gain", "pixel_offset", "target_map", "pixel_weight")


def model_to_dict(model: FourierModel) -> dict[str, Any]:
    if model.coeffs is None:
        raise ModelError("refusing to save a model without coefficients: calibrate it first")
    body: dict[str, Any] = {key: getattr(model, key) for key in _SCALAR_FIELDS}
    body["stroke_range_mm"] = list(model.stroke_range_mm)
    body["clip_gray"] = None if model.clip_gray is None else list(model.clip_gray)
    for key in _ARRAY_FIELDS:
        value = getattr(model, key)
        body[key] = None if value is None else {"shape": list(value.shape), "data": value.ravel().tolist()}
    body["pixel_noise"] = None if model.pixel_noise is None else model.pixel_noise.as_dict()
    body["info"] = model.info
    return {"schema": SCHEMA, "version": SCHEMA_VERSION, "model": body}


def model_from_dict(document: Any) -> FourierModel:
    if not isinstance(document, dict) or document.get("schema") != SCHEMA:
        found = document.get("schema") if isinstance(document, dict) else type(document).__name__
        raise ModelError(f"not a graytrack model file (schema {found!r}, expected {SCHEMA!r})")
    if document.get("version") != SCHEMA_VERSION:
        raise ModelError(f"model schema version {document.get('version')!r} is not supported (this graytrack reads {SCHEMA_VERSION})")
    body = document.get("model")
    if not isinstance(body, dict):
        raise ModelError("model file has no 'model' object")
    missing = [key for key in ("period_mm", "pixel_pitch_mm", "n_pixels", "coeffs") if body.get(key) is None]
    if missing:
        raise ModelError(f"model file lacks {missing[0]!r}")
    kwargs: dict[str, Any] = {key: body[key] for key in _SCALAR_FIELDS if key in body}
    for key in ("stroke_range_mm", "clip_gray"):
        if body.get(key) is not None:
            try:
                kwargs[key] = tuple(float(v) for v in body[key])
            except (TypeError, ValueError):
                raise ModelError(f"model file: {key} must be a pair of numbers, got {body[key]!r}") from None
            if len(kwargs[key]) != 2:
                raise ModelError(f"model file: {key} must be a pair of numbers, got {body[key]!r}")
    for key in _ARRAY_FIELDS:
        kwargs[key] = _array(body.get(key), key)
    if body.get("pixel_noise") is not None:
        kwargs["pixel_noise"] = PixelNoise.from_dict(body["pixel_noise"])
    kwargs["info"] = body.get("info") or {}
    try:
        return FourierModel(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"model file is inconsistent: {exc}") from None


def _array(entry: Any, key: str) -> np.ndarray | None:
    if entry is None:
        return None
    try:
        values = np.asarray(entry["data"], dtype=np.float64).reshape(entry["shape"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelError(f"model file: {key} is malformed ({exc})") from None
    if not np.isfinite(values).all():
        raise ModelError(f"model file: {key} holds non-finite values")
    return values


def save_model(model: FourierModel, path: str | os.PathLike[str]) -> Path:
    return write_atomic(path, json.dumps(model_to_dict(model), indent=1))


def load_model(path: str | os.PathLike[str]) -> FourierModel:
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: no such model file")
    try:
        document = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ModelError(f"{path}: not a JSON model file ({exc})") from None
    except RecursionError:
        raise ModelError(f"{path}: not a model file (JSON nested too deeply to read)") from None
    try:
        return model_from_dict(document)
    except ModelError as exc:
        raise ModelError(f"{path}: {exc}") from None
