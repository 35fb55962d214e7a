"""One frame of the virtual rig, cheaply: what a live camera driver renders at the frame rate.

:meth:`VirtualRig.render` is written for recordings: thousands of frames per call, chunked, every
effect's branch visited. A live driver asks for one frame at a time, 1,000 times a second, and there
the cost is not the arithmetic but the few dozen numpy calls around it (about 100 µs of a loaded core
per frame, as much as tracking it). Most of what those calls compute does not change from frame to
frame, so it is done once here, when the renderer is built:

- the target, the optics' blur and the vignetting are already folded into the rig's per-pixel matrix
  (``VirtualRig._matrix``, ``(2M+1, R·n)``): the light of a frame is ``basis · matrix``;
- the exposure's motion blur is linear in the basis, so the pieces of the motion are averaged into
  one basis row first (``2M+1`` numbers, scalar work) and the matrix is applied once;
- the glare (fixed to the camera) is one precomputed ``(R, n)`` array, added when present; the
  flicker and a changing room light are per-frame scalars, evaluated only when configured; a moving
  shadow is one ``(R, n)`` gain per frame, likewise;
- what changes on the camera's side (window dust, a veil, a changed vignetting) is the rig's own
  :meth:`CameraSide.apply` on the frame, with the rig's own landing state of the window's specks.

The sensor (fixed patterns, shot and read noise, gamma, quantisation) is the rig's own
:meth:`Sensor.expose` with the rig's own noise stream, so a frame is statistically — and, draw for
draw, numerically — the frame :meth:`VirtualRig.render` gives (tests/sim/test_frame_render.py).

Rigs whose light cannot be folded this way are rendered directly: a chirped, defective or growing
print (the per-pixel slow path), a light field fixed to the target, a focus that drifts, glints.
:func:`tabulable` says which, and why.
"""

from __future__ import annotations

import math
import os

import numpy as np

from graytrack.drivers.sim import illumination as illum
from graytrack.drivers.sim.rig import VirtualRig


def _exposure_basis(x: list[float], omega: list[float], out: np.ndarray) -> None:
    """The exposure-averaged real basis ``[1, cos ωx, sin ωx]`` into ``out`` ``(2M+1,)`` for the
    piecewise-linear motion through positions ``x`` (S of them): each piece (mid-point m, half-length
    h) averages ``e^{jωx}`` to ``e^{jωm}·sinc(ωh/π)`` exactly (the rig's own formula). Scalar Python
    on a dozen numbers, where numpy's per-call cost would be most of the frame; not compiled, so the
    first frame is not held up by a compilation (the frame clock runs on meanwhile)."""
    m = len(omega)
    cos_sum, sin_sum = [0.0] * m, [0.0] * m
    pieces = [(x[0], 0.0)] if len(x) == 1 else [(0.5 * (b + a), 0.5 * (b - a)) for a, b in zip(x[:-1], x[1:])]
    for mid, half in pieces:
        for i, w in enumerate(omega):
            wh = w * half
            damp = 1.0 if wh == 0.0 else math.sin(wh) / wh
            cos_sum[i] += math.cos(w * mid) * damp
            sin_sum[i] += math.sin(w * mid) * damp
    scale = 1.0 / len(pieces)
    out[0] = 1.0
    out[1:m + 1] = cos_sum
    out[m + 1:] = sin_sum
    out[1:] *= scale


def tabulable(rig: VirtualRig) -> str | None:
    """None when the rig's light folds into its per-pixel matrix; otherwise why it does not (the
    reason names the effect, so a fall-back to the direct render is never silent in a log)."""
    cfg = rig.config
    if os.environ.get("GRAYTRACK_SIM_RENDER", "").lower() == "direct":
        return "GRAYTRACK_SIM_RENDER=direct (benches compare the two renders side by side)"
    if cfg.optics.moves:
        return "a drifting magnification or a knock (what a pixel sees changes during the run)"
    if rig._slow:
        return "the print is chirped, defective or growing (every pixel evaluated on its own)"
    if cfg.illumination.has_target_field:
        return "a light field fixed to the target"
    if cfg.optics.focus_drift_mm:
        return "a drifting focus"
    if rig._glints is not None:
        return "glints"
    if cfg.timing.line_time_s and rig.n_rows > 1:
        return "a rolling shutter (every row exposed at its own time)"
    return None


class FrameRenderer:
    """Renders single frames of ``rig`` for a live camera; falls back to :meth:`VirtualRig.render`
    for rigs :func:`tabulable` refuses. ``fallback`` is that reason (None: the fast path is used)."""

    def __init__(self, rig: VirtualRig) -> None:
        self.rig = rig
        self.fallback = tabulable(rig)
        self._omega = (rig._kappa * rig._orders[1:].astype(np.float64)).tolist()  # angular frequency of each order
        self._matrix = rig._matrix  # (2M+1, R·n): target × blur × vignetting, pixel offsets folded in
        self._shape = (1, rig.n_rows, rig.n_pixels)
        icfg = rig.config.illumination
        self._illumination = icfg
        self._glare = rig._glare if icfg.glare_gray else None
        self._flicker = icfg.flicker_depth != 0.0
        self._level = icfg.level_gain != 1.0 or icfg.ambient_gray != 0.0
        self._shadow = icfg.shadow if icfg.shadow.active else None
        self._camera_side = rig.camera_side
        self._basis = np.empty(self._matrix.shape[0])  # reused: the frame's only allocation is its light

    def light(self, x_mm: np.ndarray, t_mid_s: float, exposure_s: float) -> np.ndarray:
        """Noise-free light ``(1, R, n)`` (float64) of one exposure: ``x_mm`` ``(S,)`` are the stage's
        positions at S instants evenly spaced over it (S = 1: still), as :meth:`VirtualRig.render`
        takes them. Only for rigs with ``fallback`` None."""
        positions = np.asarray(x_mm, dtype=np.float64).reshape(-1)
        _exposure_basis(positions.tolist(), self._omega, self._basis)
        light = (self._basis @ self._matrix).reshape(self._shape)
        if self._shadow is not None:  # a shadow sweeping across the field, as the rig renders it
            light *= self._shadow.gain(np.array([t_mid_s]), self.rig.geometry.x_mm)
        if self._glare is not None:
            light += self._glare
        if self._camera_side is not None:
            self._camera_side.apply(light, np.array([t_mid_s]), positions[None], exposure_s)
        if self._flicker or self._level:
            t = np.array([t_mid_s])
            gain, ambient = illum.level_change(self._illumination, t)
            light *= float((illum.flicker_gain(self._illumination, t, exposure_s) * gain)[0])
            light += float(ambient[0])
        return light

    def render(self, x_mm: np.ndarray, t_mid_s: float, exposure_s: float) -> np.ndarray:
        """One frame ``(R, n)`` in the sensor's dtype, noise from the rig's own stream (what
        ``rig.render(x_mm[None], [t_mid_s], exposure_s=exposure_s)[0]`` gives)."""
        t = np.array([t_mid_s])
        if self.fallback is not None:
            return self.rig.render(np.asarray(x_mm, dtype=np.float64).reshape(1, -1), t, exposure_s=exposure_s)[0]
        return self.rig.sensor.expose(self.light(x_mm, t_mid_s, exposure_s), self.rig._noise_rng, t)[0]
