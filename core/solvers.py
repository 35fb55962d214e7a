"""Per-frame position solvers: Gauss–Newton on a batch of frames, from a given start.

Two implementations of one small interface (``refine(k, x_start)``, ``grid_cost(k, grid)``): the
fast path for models whose coefficients do not depend on x, and the general one for everything
else (stroke-dependent coefficients, per-frame gain/offset, clipping, a target map).
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from graytrack.core.evaluation import ClippedHarmonics, FastHarmonics, GeneralHarmonics
from graytrack.core.models.fourier import TWO_PI, FourierModel


@dataclass
class FrameSolution:
    x_mm: float
    rms_gray: float
    information: float  # Σ (∂F/∂x)² after any per-frame nuisance is profiled out
    iterations: int
    gain: float = 1.0
    offset: float = 0.0


class GeneralBatch:
    """Gauss–Newton on frames with any model: per iteration one model evaluation at one x.

    Handles what the fast path cannot: coefficients that drift along the stroke, a per-frame
    gain/offset solved together with x, and saturated pixels.
    """

    def __init__(self, model: FourierModel, prepared: np.ndarray, max_iterations: int, tolerance_mm: float,
                 evaluator: "FastHarmonics | GeneralHarmonics | ClippedHarmonics"):
        self.model = model
        self.frames = prepared.reshape(prepared.shape[0], -1)
        self.evaluator = evaluator
        self.max_iterations, self.tolerance_mm = max_iterations, tolerance_mm
        self.max_step_mm = model.period_mm / 4.0

    def refine(self, k: int, x_start: float) -> FrameSolution:
        y = self.frames[k]
        x, gain, offset = float(x_start), 1.0, 0.0
        common_mode = self.model.common_mode
        iterations = 0
        for iterations in range(1, self.max_iterations + 1):
            values, slopes = self.evaluator.evaluate(np.array([x]))
            values, slopes = values[0], slopes[0]
            residual = y - (gain * values + offset)
            if common_mode:
                jac = np.stack([gain * slopes, values, np.ones_like(values)], axis=1)
                delta = np.linalg.solve(jac.T @ jac, jac.T @ residual)
                dx = float(delta[0])
                gain, offset = gain + float(delta[1]), offset + float(delta[2])
            else:
                dx = float(slopes @ residual) / float(slopes @ slopes)
            dx = min(max(dx, -self.max_step_mm), self.max_step_mm)
            x += dx
            if abs(dx) < self.tolerance_mm:
                break
        values, slopes = self.evaluator.evaluate(np.array([x]))
        residual = y - (gain * values[0] + offset)
        rms = float(np.sqrt(residual @ residual / y.size))
        return FrameSolution(x, rms, self._information(values[0], slopes[0], gain), iterations, gain, offset)

    def _information(self, values: np.ndarray, slopes: np.ndarray, gain: float) -> float:
        d_x = gain * slopes
        info = float(d_x @ d_x)
        if self.model.common_mode:
            nuisance = np.stack([values, np.ones_like(values)], axis=1)
            cross = nuisance.T @ d_x
            info -= float(cross @ np.linalg.solve(nuisance.T @ nuisance, cross))
        return info

    def grid_cost(self, k: int, grid: np.ndarray) -> np.ndarray:
        values, _ = self.evaluator.evaluate(grid)
        y = self.frames[k]
        if not self.model.common_mode:
            return ((y[None] - values) ** 2).sum(axis=1)
        centred_v = values - values.mean(axis=1, keepdims=True)
        centred_y = y - y.mean()
        scale = (centred_v @ centred_y) / np.maximum((centred_v**2).sum(axis=1), 1e-300)
        return ((centred_y[None] - scale[:, None] * centred_v) ** 2).sum(axis=1) + 1e12 * (scale <= 0)


class TrigPolyBatch:
    """The fast path: each frame reduced to M complex numbers, then a scalar solve per frame.

    For a model whose coefficients do not depend on x, every quantity Gauss–Newton needs is a
    trigonometric polynomial in x: y·F(x) = y·c + Re Σ_h β_h z^h with β = V·y (one matrix product
    for all frames), and ‖F‖², ‖F′‖² have frame-independent coefficients (found once by FFT).
    The per-frame loop then does a few dozen scalar operations instead of array work.
    """

    def __init__(self, model: FourierModel, prepared: np.ndarray, max_iterations: int, tolerance_mm: float,
                 fast: FastHarmonics, gram: tuple[np.ndarray, np.ndarray]):
        frames = prepared.reshape(prepared.shape[0], -1)
        self.n_values = frames.shape[1]
        self.omega = TWO_PI / model.period_mm
        self.max_iterations, self.tolerance_mm = max_iterations, tolerance_mm
        self.max_step_mm = model.period_mm / 4.0
        self.harmonics = model.harmonics
        self.beta = frames @ fast.v.T  # (K, M)
        self.y_dot_c = frames @ fast.constant
        self.y_norm = np.einsum("kp,kp->k", frames, frames)
        self.q, self.d = gram
        degree = 2 * self.harmonics
        orders = np.arange(1, degree + 1)
        padded_beta = np.zeros((frames.shape[0], degree), dtype=complex)
        padded_beta[:, : self.harmonics] = self.beta
        # Per frame, as coefficients of z^1..z^2M:
        #   F′·(y − F) = Re Σ step_m z^m        (the Gauss–Newton numerator)
        #   ‖y − F‖² = cost_0 + Re Σ cost_m z^m
        step = padded_beta * (1j * self.omega * orders) - 0.5 * self.q[1:] * (1j * self.omega * orders)
        self._step_rows = step.tolist()
        self._cost_rows = (self.q[1:] - 2.0 * padded_beta).tolist()
        self._cost_const = (self.y_norm - 2.0 * self.y_dot_c + self.q[0].real).tolist()
        self._info_coeffs = self.d[1:].tolist()
        self._info_const = float(self.d[0].real)

    def refine(self, k: int, x_start: float) -> FrameSolution:
        step_coeffs, info_coeffs = self._step_rows[k], self._info_coeffs
        omega, degree, max_step = self.omega, 2 * self.harmonics, self.max_step_mm
        x = float(x_start)
        iterations = 0
        powers: list[complex] = []
        information = 1.0
        for iterations in range(1, self.max_iterations + 1):
            powers = _powers(cmath.exp(1j * omega * x), degree)
            numerator = sum([(c * p).real for c, p in zip(step_coeffs, powers)])
            information = self._info_const + sum([(c * p).real for c, p in zip(info_coeffs, powers)])
            dx = min(max(numerator / information, -max_step), max_step)
            x += dx
            if abs(dx) < self.tolerance_mm:
                break
        # Residual and information at the last evaluated point: the final step is below tolerance.
        cost = self._cost_const[k] + sum([(c * p).real for c, p in zip(self._cost_rows[k], powers)])
        return FrameSolution(x, math.sqrt(max(cost, 0.0) / self.n_values), information, iterations)

    def grid_cost(self, k: int, grid: np.ndarray) -> np.ndarray:
        z = np.exp(1j * self.omega * np.outer(grid, np.arange(2 * self.harmonics + 1)))  # (G, 2M+1)
        model_norm = (z @ self.q).real
        cross = self.y_dot_c[k] + (z[:, 1:self.harmonics + 1] @ self.beta[k]).real
        return self.y_norm[k] - 2.0 * cross + model_norm


def _powers(z: complex, count: int) -> list[complex]:
    """[z, z², …, z^count]."""
    out = [z]
    for _ in range(count - 1):
        out.append(out[-1] * z)
    return out
