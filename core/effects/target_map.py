"""A relative reflectance map along the target: dust, scratches, print flaws fixed to the target.

The map has a row for each row of the model: one on a model of the rows' mean, one per row on a
per-row model (and a map found before the rows were told apart becomes one per row when they are).
A dust spot or a scratch at an angle is two-dimensional, and rows a pixel footprint apart see it
differently: a map the rows shared would hold their mean, too deep on the rows that miss the spot
and too shallow on those that see it; tracking would leave a residual on every frame with a spot
in view, and a robust solve that sets the spot's samples aside keeps the shared map's wrong dip on
the other rows, which pulls the position (1.47 µm against a 0.51 µm bound on a 16-row lab strip
with six spots, 0.58 µm with a map a row)."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import solveh_banded

from graytrack.core.basis import trig_basis
from graytrack.core.effects import Effect
from graytrack.core.models.fourier import TWO_PI, FourierModel
from graytrack.core.evidence import Evidence, explains, model_rows, share_above_noise

DEFAULT_MAP_STEPS = 2  # half a pixel footprint: finer grids are noisier, coarser ones blur dust
MAX_MAP_STEPS = 4  # a quarter of a pixel footprint, for defects narrower than a pixel (scratches)
TARGET_MAP_RIDGE = 1e-3


def fit_target_map(model: FourierModel, x_mm: np.ndarray, lit: np.ndarray, smooth: np.ndarray,
                   weights: np.ndarray, steps_per_pixel: int = DEFAULT_MAP_STEPS) -> dict[str, Any]:
    """Relative reflectance m(x_w) on a grid along the target, a row for each model row, from
    lit ≈ S·(1 + m(x_w)).

    Piecewise-linear (hat) basis: the normal matrix is tridiagonal, accumulated with bincount and
    solved banded (the rows' blocks one band, uncoupled). What the Fourier × polynomial part can
    already say (anything periodic or smooth along the target) is projected out, so the map holds
    only local defects.
    """
    step = model.pixel_pitch_mm / steps_per_pixel
    x_w = model.target_coordinate(x_mm)
    origin = float(x_w.min()) - step
    size = int(np.ceil((float(x_w.max()) + step - origin) / step)) + 1  # the last cell's right node included
    position = (x_w - origin) / step
    cell = np.floor(position).astype(np.int64)
    frac = (position - cell).reshape(-1)
    map_rows = model.n_rows
    if map_rows > 1:  # each row's nodes after the previous row's: no cell reaches its row's last node
        cell = cell + size * np.arange(map_rows)[:, None]
    cell, total = cell.reshape(-1), size * map_rows
    signal, w = smooth.reshape(-1), np.broadcast_to(weights, smooth.shape).reshape(-1)
    target = (lit - smooth).reshape(-1)
    left, right = signal * (1.0 - frac), signal * frac
    diag = np.bincount(cell, w * left * left, total) + np.bincount(cell + 1, w * right * right, total)
    off = np.bincount(cell, w * left * right, total)[:-1]
    rhs = np.bincount(cell, w * left * target, total) + np.bincount(cell + 1, w * right * target, total)
    ridge = TARGET_MAP_RIDGE * max(float(diag.mean()), 1e-300)
    banded = np.zeros((2, total))
    banded[0, 1:], banded[1] = off, diag + ridge
    values = solveh_banded(banded, rhs).reshape(map_rows, size)
    nodes = origin + step * np.arange(size)
    periodic = trig_basis(TWO_PI * nodes / model.period_mm, model.harmonics)
    coef, *_ = np.linalg.lstsq(periodic, values.T, rcond=None)
    return {"target_map": values - (periodic @ coef).T, "target_map_origin_mm": origin, "target_map_step_mm": step}


class TargetMap(Effect):
    name = "target_map"
    frame_part = "target map"  # core/frame_tables.py: what tracking reads of it
    family = "local defects fixed to the target (dust, scratches, print flaws)"
    adds = ("a relative reflectance map on a half-pixel grid along the target (its periodic part left to the "
            "Fourier terms), a row for each model row")
    fitted = ("tridiagonal least squares, alternating with the smooth part; tracking uses its slope too; a second "
              "step halves the grid")
    order = 20  # before the flat field: it divides the light the flat field then scales
    bilinear = True
    search_pitch = True

    def probe(self, stage):
        """A fine map along the target coordinate, learnt from training frames, predicts the
        held-out residual wherever the same spot is seen."""

        train, val = stage.train, stage.val
        model = train.model
        steps = DEFAULT_MAP_STEPS
        if model.target_map is not None:  # a map exists: would one twice as fine say more?
            steps = 2 * int(round(model.pixel_pitch_mm / model.target_map_step_mm))
            if steps > MAX_MAP_STEPS:
                return None
        (res_t, use_t, _), (res_v, use_v, factor) = model_rows(train), model_rows(val)
        found = fit_target_map(model.with_changes(coeffs=model.coeffs, target_map=None), train.data.x_mm,
                               train.smooth + res_t, train.smooth, use_t, steps)
        mapped = model.with_changes(coeffs=model.coeffs, **found)
        predicted = val.smooth * (mapped.target_factor(val.data.x_mm)[0] - 1.0) * use_v
        explained = factor * float((res_v**2).sum() - ((res_v - predicted) ** 2).sum())
        sigma2 = val.data.sigma_gray**2
        share = share_above_noise(explained, train, val)  # learnt on training frames: cross-validated
        deepest = float(np.abs(found["target_map"]).max()) * 100
        rows = " a row" if found["target_map"].shape[0] > 1 else ""
        return Evidence(self.name, "target coordinate (local)", explained,
                        explained / sigma2 / np.sqrt(2.0 * found["target_map"].size), share,
                        f"spots fixed to the target (deepest {deepest:.1f}% of the light, on a "
                        f"{found['target_map_step_mm'] * 1e3:.0f} µm grid{rows}) {explains(share)}")

    def grow(self, spec, argument):
        current = spec.get(self.name)
        steps = 2 * current if current else DEFAULT_MAP_STEPS
        return spec.set(self.name, steps) if steps <= MAX_MAP_STEPS else None

    def fit_step(self, setting, state):
        mapped_fields = fit_target_map(state.model, state.x_mm, state.lit, state.smooth, state.weights, setting)
        state.found.update(mapped_fields)  # (other effects keep their own findings in ``found`` too)
        mapped = state.model.with_changes(coeffs=state.model.coeffs, **mapped_fields)
        state.map_factor = mapped.target_factor(state.x_mm)[0]

    def finish(self, setting, state, model):
        keys = ("target_map", "target_map_origin_mm", "target_map_step_mm")
        return model.with_changes(coeffs=model.coeffs, **{key: state.found[key] for key in keys})


EFFECT = TargetMap()
