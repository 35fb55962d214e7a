"""Which family of causes a frame's residual points to, from the shapes each family leaves.

When the model stops fitting, the residual of a frame (weighted by the noise, so that every sample
counts by its information) is compared with the shapes each family of causes can leave in it:
- ``pixels``: a few samples carry most of it (a pixel gone bad, a glint, dust on the sensor);
- ``light``: the model times a smooth gain across the line, plus a smooth offset (a lamp, stray
  light, a shadow);
- ``focus``: a change of blur, which for a Gaussian spreads like heat: ∂F/∂(σ²) = ½·∂²F/∂x²;
- ``print``: a profile of its own along the target's phase (harmonics of it: a print that is not
  the calibrated one, dot gain, humidity), named ``geometry`` with the rest of what makes the
  image other than the model describes (a moved camera, a mirrored axis, a wrong period);
- ``geometry``: none of these.
Each family's evidence is the χ² its shapes explain beyond what noise alone would give them (one
per shape), as a share of the residual's excess over the noise, so a family with more shapes gets
no credit for fitting noise.

On a line shorter than a period the light's six shapes can mimic almost anything in one frame (a
changed print harmonic too). What one frame cannot show, the frames together do: a light or a
focus that changed keeps its coefficients from frame to frame, while a mimicry's coefficients turn
with the phase of the print. :class:`Consistency` measures that, and a family is named only for
the part of its share its coefficients hold still.
"""

from __future__ import annotations

import functools

import numpy as np

LIGHT_DEGREE = 2  # gain and offset across the line up to quadratic in the pixel index
SHARE_TO_NAME = 0.5  # a family that explains at least this share of the excess is named
# A print of its own can take any profile, a light's or a focus's too: it is named only when it
# explains clearly more than the most specific family does.
PRINT_MARGIN = 0.1


@functools.lru_cache(maxsize=8)
def _smooth_basis(n_pixels: int, n_rows: int) -> np.ndarray:
    """Legendre polynomials up to :data:`LIGHT_DEGREE` across the line, tiled over the rows, one
    shape per row ``(3, P)``: the same for every frame of a model, so computed once (read-only)."""
    u = np.tile(np.linspace(-1.0, 1.0, n_pixels), n_rows)
    smooth = np.ascontiguousarray(np.polynomial.legendre.legvander(u, LIGHT_DEGREE).T)
    smooth.flags.writeable = False
    return smooth


def _harmonic_rows(phase: np.ndarray, harmonics: int) -> np.ndarray:
    """cos(h·phase) for h = 1..H, then sin(h·phase), one shape per row ``(2H, P)``: one cosine and
    one sine of the phase, the higher harmonics by the angle-addition recurrence (a frame's shapes
    cost no more trigonometry as the model's harmonics grow)."""
    out = np.empty((2 * harmonics, phase.size))
    cos1, sin1 = out[0], out[harmonics]
    np.cos(phase, out=cos1)
    np.sin(phase, out=sin1)
    for h in range(1, harmonics):
        c, s = out[h - 1], out[harmonics + h - 1]
        out[h] = c * cos1 - s * sin1
        out[harmonics + h] = s * cos1 + c * sin1
    return out


def shapes(values: np.ndarray, slopes: np.ndarray, curvature: np.ndarray, n_rows: int,
           phase: np.ndarray | None = None, harmonics: int = 0) -> dict[str, np.ndarray]:
    """The columns ``(P, k)`` each family can add to a frame's model at one position; ``phase``
    ``(P,)`` is the target phase each sample sees (2π·target coordinate / period). (Each is the
    transpose of a row-per-shape array: :func:`shares` reads the shapes along the samples.)"""
    smooth = _smooth_basis(values.size // n_rows, n_rows)
    light = np.concatenate([smooth * values, smooth])
    columns = {"light": light.T, "focus": 0.5 * curvature[:, None], "shift": slopes[:, None]}
    if phase is not None and harmonics > 0:
        columns["print"] = _harmonic_rows(np.asarray(phase, dtype=np.float64), harmonics).T
    return columns


def shares(residual: np.ndarray, weights: np.ndarray,
           columns: dict[str, np.ndarray]) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Each family's share of the excess χ² of a residual ``(P,)`` with weights 1/σ² ``(P,)``, and
    the coefficients of its shapes.

    ``pixels`` is the share of the largest few samples (2 % of them, at least 2); the others are
    least-squares projections onto the family's columns (together with the shift in x, which the
    solve already took out, so that a family is not credited with a position error). A family's
    shapes can include the shift itself (a print's harmonics span the model's slope): the
    minimum-norm solution then stands for the family, as the frames' consistency reads it."""
    used = weights > 0
    every = bool(used.all())  # (numpy's boolean indexing is slower than compress)
    root = np.sqrt(weights if every else weights.compress(used))
    z = (residual if every else residual.compress(used)) * root
    total = float(z @ z)
    excess = total - z.size
    if z.size < 8 or excess <= 0:
        return {}, {}
    out: dict[str, float] = {}
    found: dict[str, np.ndarray] = {}
    n_top = max(2, z.size // 50)
    top = np.partition(z * z, z.size - n_top)[-n_top:]
    out["pixels"] = float(np.clip((top.sum() - n_top) / excess, 0.0, 1.0))
    for family in (name for name in ("light", "focus", "print") if name in columns):
        basis = np.concatenate([columns[family], columns["shift"]], axis=1)
        basis = (basis if every else basis.compress(used, axis=0)) * root[:, None]
        coefficients, *_ = np.linalg.lstsq(basis, z, rcond=None)
        explained = float(np.sum((basis @ coefficients) ** 2))
        out[family] = float(np.clip((explained - basis.shape[1]) / excess, 0.0, 1.0))
        found[family] = coefficients[:-1]
    return out, found


class Consistency:
    """How still a family's coefficients hold over frames: |mean|² / mean of |c|², running (1: the
    same every frame, as a real change of the light or the focus; near 0: turning with the print)."""

    def __init__(self, window: int):
        self.window = window
        self.mean: np.ndarray | None = None
        self.square = 0.0

    def add(self, coefficients: np.ndarray) -> float:
        if self.mean is None or self.mean.shape != coefficients.shape:
            self.mean, self.square = coefficients.astype(float).copy(), float(coefficients @ coefficients)
        else:
            self.mean += (coefficients - self.mean) / self.window
            self.square += (float(coefficients @ coefficients) - self.square) / self.window
        return self.value

    @property
    def value(self) -> float:
        return float(self.mean @ self.mean / self.square) if self.mean is not None and self.square > 0 else 0.0


def named(average_shares: dict[str, float]) -> str:
    """The family a running average of shares points to (``geometry`` when none stands out)."""
    if not average_shares:
        return "geometry"
    specific = {family: share for family, share in average_shares.items() if family != "print"}
    family, share = max(specific.items(), key=lambda item: item[1]) if specific else ("geometry", 0.0)
    if average_shares.get("print", 0.0) > share + PRINT_MARGIN:
        return "geometry"
    return family if share >= SHARE_TO_NAME else "geometry"
