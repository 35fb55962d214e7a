"""Model files: JSON with a schema name and version, so a file from another tool or a future
incompatible graytrack is refused by name instead of being half-read."""

from __future__ import annotations

import dataclasses
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

def _codec(annotation: str) -> str:
    """How a FourierModel field is written, from its type: arrays as shape + data, tuples as lists,
    the noise model as its own object, everything else as it is."""
    for kind in ("ndarray", "PixelNoise", "tuple"):
        if kind in annotation:
            return kind
    return "plain"


def _fields() -> dict[str, str]:
    """Every model field that a file holds, with its codec (derived from the dataclass, so a new
    field of the model is saved and loaded without being listed here)."""
    return {f.name: _codec(str(f.type)) for f in dataclasses.fields(FourierModel) if f.init}


def _encode(value: Any, codec: str) -> Any:
    if value is None:
        return None
    if codec == "ndarray":
        return {"shape": list(value.shape), "data": value.ravel().tolist()}
    if codec == "PixelNoise":
        return value.as_dict()
    if codec == "tuple":
        return list(value)
    return value


def _decode(value: Any, codec: str, key: str) -> Any:
    if value is None:
        return None
    if codec == "ndarray":
        return _array(value, key)
    if codec == "PixelNoise":
        return PixelNoise.from_dict(value)
    if codec == "tuple":
        try:
            pair = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            pair = ()
        if len(pair) != 2:  # every tuple field of the model is a (low, high) pair
            raise ModelError(f"model file: {key} must be a pair of numbers, got {value!r}")
        return pair
    return value


def model_to_dict(model: FourierModel) -> dict[str, Any]:
    if model.coeffs is None:
        raise ModelError("refusing to save a model without coefficients: calibrate it first")
    body = {key: _encode(getattr(model, key), codec) for key, codec in _fields().items()}
    return {"schema": SCHEMA, "version": SCHEMA_VERSION, "model": body}


def model_from_dict(document: Any) -> FourierModel:
    if not isinstance(document, dict) or document.get("schema") != SCHEMA:
        found = document.get("schema") if isinstance(document, dict) else type(document).__name__
        raise ModelError(f"not a graytrack model file (schema {found!r}, expected {SCHEMA!r})")
    if document.get("version") != SCHEMA_VERSION:
        raise ModelError(f"model schema version {document.get('version')!r} is not supported (this graytrack reads "
                         f"{SCHEMA_VERSION})")
    body = document.get("model")
    if not isinstance(body, dict):
        raise ModelError("model file has no 'model' object")
    missing = [key for key in ("period_mm", "pixel_pitch_mm", "n_pixels", "coeffs") if body.get(key) is None]
    if missing:
        raise ModelError(f"model file lacks {missing[0]!r}")
    kwargs = {key: _decode(body[key], codec, key) for key, codec in _fields().items() if key in body}
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
