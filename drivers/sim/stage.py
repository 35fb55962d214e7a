"""The simulated linear stage: trapezoidal moves, a servo loop with following error and settling.

A real stage does not sit exactly where it was told to be: the controller plans a trapezoidal
velocity profile (velocity and acceleration limits), and the servo loop follows that plan with a
lag that grows with velocity (following error) and rings after every change of acceleration
(settling). The camera and the grating both see the *actual* position, so these effects change what
is recorded and when a step-and-settle sweep may take its frame, not the camera/grating agreement.

The servo is modelled as a second-order loop with velocity and acceleration feed-forward::

    x'' + 2ζω (x' - k_v p') + ω² (x - p) = k_a p''

where ``p(t)`` is the commanded profile. With ``e = x - p`` the error obeys a damped oscillator
driven by the commanded velocity and acceleration; on each segment of constant commanded
acceleration its solution is closed-form, so positions are evaluated exactly and vectorised over
any array of times (no time stepping, no integration error, no dependence on a frame rate).

Commands (``move_to``, ``stop``) must come in non-decreasing time order; queries (``position``,
``velocity``) may ask about any time, past or future: the answer is the motion as planned by the
commands issued so far. A command at time ``t`` replaces the plan from ``t`` on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol, runtime_checkable

import numpy as np

ArrayLike = float | np.ndarray
ROW_FIELDS = ("t0", "p0", "v0", "a", "c0", "c1", "A", "B")  # a segment's constants, in _servo_positions' order
FEW_INSTANTS = 8  # up to this many instants, a position is computed in scalar arithmetic (a live camera's frame)


@runtime_checkable
class Trajectory(Protocol):
    """Anything that tells the true stage position and velocity at given times (vectorised)."""

    def position(self, t_s: ArrayLike) -> np.ndarray: ...

    def velocity(self, t_s: ArrayLike) -> np.ndarray: ...


@dataclass
class SimStageConfig:
    """Limits, current motion settings and servo behaviour of the simulated stage."""

    velocity_mm_s: float = 5.0  # current move velocity (PI: VEL)
    acceleration_mm_s2: float = 100.0  # current acceleration = deceleration (PI: ACC/DEC)
    max_velocity_mm_s: float = 50.0  # hardware limit; setters refuse more
    max_acceleration_mm_s2: float = 2000.0
    soft_limits_mm: tuple[float, float] = (-1.0, 26.0)
    bandwidth_hz: float = 80.0  # servo natural frequency ω/2π
    damping: float = 0.8  # servo damping ratio ζ (< 1)
    velocity_feedforward: float = 0.97  # k_v: 1 = no velocity following error
    acceleration_feedforward: float = 0.9  # k_a: 1 = no acceleration-driven error
    on_target_window_mm: float = 0.0005  # PI: settle window
    settle_time_s: float = 0.01  # PI: settle time
    vibration_mm: float = 0.0  # amplitude of a structural vibration riding on the motion
    vibration_hz: float = 180.0
    vibration_phase_rad: float = 0.0


class SoftLimitError(ValueError):
    """A move target outside the configured soft limits (the controller refuses it)."""


@dataclass
class _Segment:
    """Commanded motion with constant acceleration from ``t0`` on, plus the servo error state."""

    t0: float
    p0: float
    v0: float
    a: float
    e0: float  # actual - commanded at t0
    ed0: float  # its time derivative


class SimStage:
    """One simulated axis. Implements :class:`Trajectory` (``position``/``velocity`` over arrays).

    ``position(t)`` is the actual (servo) position, ``commanded_position(t)`` the planned profile;
    ``following_error(t)`` is their difference. ``move_to`` returns the time at which the planned
    profile arrives; the servo settles shortly after (see ``on_target``).
    """

    def __init__(self, config: SimStageConfig | None = None, position_mm: float = 0.0, t_s: float = 0.0):
        self.config = config if config is not None else SimStageConfig()
        self._check_limits(position_mm)
        self._segments: list[_Segment] = [_Segment(float(t_s), float(position_mm), 0.0, 0.0, 0.0, 0.0)]
        self._last_command_t = float(t_s)
        self._target_mm = float(position_mm)
        # created at rest and settled already: a controller that has just powered up answers on target
        # at once, not after its settle time (a client's first query can come within milliseconds)
        self._t_end = float(t_s) - self.config.settle_time_s
        self._rebuild()

    # ----- settings -------------------------------------------------------------------------
    @property
    def soft_limits_mm(self) -> tuple[float, float]:
        return self.config.soft_limits_mm

    @soft_limits_mm.setter
    def soft_limits_mm(self, limits: tuple[float, float]) -> None:
        low, high = float(limits[0]), float(limits[1])
        if not low < high:
            raise ValueError(f"soft limits must satisfy low < high, got {limits}")
        self.config.soft_limits_mm = (low, high)

    @property
    def velocity_mm_s(self) -> float:
        return self.config.velocity_mm_s

    @velocity_mm_s.setter
    def velocity_mm_s(self, value: float) -> None:
        if not 0 < value <= self.config.max_velocity_mm_s:
            raise ValueError(f"velocity must be in (0, {self.config.max_velocity_mm_s}] mm/s, got {value}")
        self.config.velocity_mm_s = float(value)

    def set_velocity(self, value: float) -> None:
        """Velocity for the next moves (a move in progress keeps its plan, as on a PI controller)."""
        self.velocity_mm_s = value

    @property
    def acceleration_mm_s2(self) -> float:
        return self.config.acceleration_mm_s2

    @acceleration_mm_s2.setter
    def acceleration_mm_s2(self, value: float) -> None:
        if not 0 < value <= self.config.max_acceleration_mm_s2:
            raise ValueError(
                f"acceleration must be in (0, {self.config.max_acceleration_mm_s2}] mm/s², got {value}"
            )
        self.config.acceleration_mm_s2 = float(value)

    @property
    def target_mm(self) -> float:
        """Target of the last move (or the stop position after ``stop``)."""
        return self._target_mm

    @property
    def peak_acceleration_mm_s2(self) -> float:
        """The largest acceleration its commands asked for (what its owner knows of the motion)."""
        return max((abs(segment.a) for segment in self._segments), default=0.0)

    def acceleration_phases(self) -> list[tuple[float, float, float]]:
        """The planned profile's phases of constant nonzero acceleration: (start s, end s, |acceleration| mm/s²),
        what the controller was told and its owner knows (the servo follows within its bandwidth)."""
        segments = self._segments
        return [(segment.t0, following.t0, abs(segment.a))
                for segment, following in zip(segments, segments[1:]) if segment.a != 0.0]

    # ----- commands -------------------------------------------------------------------------
    def move_to(self, target_mm: float, t_s: float) -> float:
        """Command an absolute move at time ``t_s``; returns the planned arrival time.

        Raises :class:`SoftLimitError` outside the soft limits (nothing changes then). A move
        issued while moving blends from the current commanded position and velocity.
        """
        target_mm = float(target_mm)
        self._check_limits(target_mm)
        t_s = self._command_time(t_s)
        p, v = self._commanded_state(t_s)
        phases = _plan(p, v, target_mm, self.config.velocity_mm_s, self.config.acceleration_mm_s2)
        self._replace_plan(t_s, phases, rest_at=target_mm)
        self._target_mm = target_mm
        return self._t_end

    def move_by(self, delta_mm: float, t_s: float) -> float:
        """Relative move from the current target (PI: MVR)."""
        return self.move_to(self._target_mm + float(delta_mm), t_s)

    def stop(self, t_s: float) -> float:
        """Decelerate to rest at the set acceleration; returns the time at which it rests."""
        t_s = self._command_time(t_s)
        p, v = self._commanded_state(t_s)
        acc = self.config.acceleration_mm_s2
        phases = [(abs(v) / acc, -math.copysign(acc, v))] if v != 0 else []
        rest = p + v * abs(v) / (2 * acc)
        self._replace_plan(t_s, phases, rest_at=rest)
        self._target_mm = rest
        return self._t_end

    # ----- queries (vectorised) -------------------------------------------------------------
    def position(self, t_s: ArrayLike) -> np.ndarray:
        """Actual (servo) position in mm at time(s) ``t_s``. Only what the position needs is
        evaluated: a live camera asks for it three times per frame, at 1 kHz."""
        arr, omega, zeta = self._arrays, self._omega(), self._zeta()  # one plan, whatever a command replaces meanwhile
        t = np.asarray(t_s, dtype=np.float64)
        if t.size <= FEW_INSTANTS:
            out = _servo_positions(arr, t.reshape(-1), omega, zeta)
            return out[0] if t.ndim == 0 else out.reshape(t.shape)  # a number for a number, as numpy gives
        p, _, e, _ = _eval_segments(arr, *_locate(arr, t), omega, zeta)
        return p + e

    def velocity(self, t_s: ArrayLike) -> np.ndarray:
        """Actual velocity in mm/s at time(s) ``t_s``."""
        _, v, _, ed = self._evaluate(t_s)
        return v + ed

    def commanded_position(self, t_s: ArrayLike) -> np.ndarray:
        """The controller's planned (trapezoidal) position profile."""
        return self._evaluate(t_s)[0]

    def following_error(self, t_s: ArrayLike) -> np.ndarray:
        """Commanded minus actual position (positive when the stage lags a forward move)."""
        return -self._evaluate(t_s)[2]

    def on_target(self, t_s: float) -> bool:
        """PI-style on-target: motion finished and within the window for the whole settle time."""
        cfg = self.config
        t_s = float(t_s)
        if t_s - cfg.settle_time_s < self._t_end:
            return False
        probe = np.linspace(t_s - cfg.settle_time_s, t_s, 16)
        return bool(np.all(np.abs(self.position(probe) - self._target_mm) <= cfg.on_target_window_mm))

    def settled_time(self, t_from: float, horizon_s: float = 5.0, step_s: float = 1e-4) -> float:
        """First time ≥ ``t_from`` at which ``on_target`` holds (NaN if not within ``horizon_s``)."""
        cfg = self.config
        start = max(float(t_from), self._t_end)
        times = np.arange(start, start + horizon_s, step_s)
        inside = np.abs(self.position(times) - self._target_mm) <= cfg.on_target_window_mm
        # last time it was outside, then settle time later
        outside = np.flatnonzero(~inside)
        first_inside = times[outside[-1] + 1] if outside.size else start
        if outside.size and outside[-1] + 1 >= times.size:
            return float("nan")
        return float(max(first_inside, self._t_end) + cfg.settle_time_s)

    # ----- internals --------------------------------------------------------------------------
    def _check_limits(self, x: float) -> None:
        low, high = self.config.soft_limits_mm
        if not low <= x <= high:
            raise SoftLimitError(f"target {x:.6g} mm outside soft limits [{low:g}, {high:g}] mm")

    def _command_time(self, t_s: float) -> float:
        t_s = float(t_s)
        if t_s < self._last_command_t:
            raise ValueError(f"commands must come in time order: {t_s} < {self._last_command_t}")
        self._last_command_t = t_s
        return t_s

    def _commanded_state(self, t_s: float) -> tuple[float, float]:
        p, v, _, _ = self._evaluate(np.array([t_s]))
        return float(p[0]), float(v[0])

    def _replace_plan(self, t_s: float, phases: list[tuple[float, float]], rest_at: float) -> None:
        p, v, e, ed = (float(q[0]) for q in self._evaluate(np.array([t_s])))
        kept = [s for s in self._segments if s.t0 < t_s]
        t = t_s
        for duration, acc in phases:
            if duration <= 0:
                continue
            kept.append(_Segment(t, p, v, acc, e, ed))
            p, v, e, ed = self._advance(kept[-1], duration)
            t += duration
        # rest exactly at the planned point (removes round-off from the phase arithmetic)
        kept.append(_Segment(t, rest_at, 0.0, 0.0, e + (p - rest_at), ed + v))
        self._segments = kept
        self._t_end = t
        self._rebuild()

    def _advance(self, seg: _Segment, tau: float) -> tuple[float, float, float, float]:
        arrays = _segment_arrays([seg], self._omega(), self._zeta(), self.config)
        out = _eval_segments(arrays, np.zeros(1, dtype=int), np.array([tau]), self._omega(), self._zeta())
        return tuple(float(q[0]) for q in out)  # type: ignore[return-value]

    def _omega(self) -> float:
        return 2 * math.pi * self.config.bandwidth_hz

    def _zeta(self) -> float:
        return min(max(self.config.damping, 1e-3), 0.999)

    def _rebuild(self) -> None:
        self._arrays = _segment_arrays(self._segments, self._omega(), self._zeta(), self.config)

    def _evaluate(self, t_s: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        arr = self._arrays
        idx, tau = _locate(arr, t_s)
        return _eval_segments(arr, idx, tau, self._omega(), self._zeta())


def _plan(p: float, v: float, target: float, vmax: float, acc: float) -> list[tuple[float, float]]:
    """Phases (duration, acceleration) taking the commanded state (p, v) to rest at ``target``."""
    d = target - p
    if d == 0 and v == 0:
        return []
    sgn = math.copysign(1.0, d) if d != 0 else -math.copysign(1.0, v)
    stop_dist = v * v / (2 * acc)
    if v * sgn < 0 or stop_dist > abs(d) + 1e-15:
        # moving away or unable to stop in time: come to rest first, then plan from rest
        dt = abs(v) / acc
        p_rest = p + v * dt / 2
        return [(dt, -math.copysign(acc, v))] + _plan(p_rest, 0.0, target, vmax, acc)
    vs, dist = abs(v), abs(d)
    vp = min(vmax, math.sqrt(acc * dist + vs * vs / 2))
    t1 = abs(vp - vs) / acc
    d1 = (vp + vs) / 2 * t1
    d3 = vp * vp / (2 * acc)
    t2 = max(dist - d1 - d3, 0.0) / vp
    return [(t1, sgn * math.copysign(acc, vp - vs)), (t2, 0.0), (vp / acc, -sgn * acc)]


def _segment_arrays(segments: list[_Segment], omega: float, zeta: float, cfg: SimStageConfig) -> dict[str, np.ndarray]:
    """Per-segment constants of the closed-form servo error (particular + damped homogeneous part)."""
    t0 = np.array([s.t0 for s in segments])
    p0 = np.array([s.p0 for s in segments])
    v0 = np.array([s.v0 for s in segments])
    a = np.array([s.a for s in segments])
    e0 = np.array([s.e0 for s in segments])
    ed0 = np.array([s.ed0 for s in segments])
    # e'' + 2ζω e' + ω² e = g0 + g1 τ  with  g = -(1-k_a) a - 2ζω (1-k_v)(v0 + a τ)
    g1 = -2 * zeta * omega * (1 - cfg.velocity_feedforward) * a
    g0 = -(1 - cfg.acceleration_feedforward) * a - 2 * zeta * omega * (1 - cfg.velocity_feedforward) * v0
    c1 = g1 / omega**2
    c0 = (g0 - 2 * zeta * omega * c1) / omega**2
    omega_d = omega * math.sqrt(1 - zeta * zeta)
    h0 = e0 - c0
    hd0 = ed0 - c1
    arrays = {
        "t0": t0, "p0": p0, "v0": v0, "a": a, "c0": c0, "c1": c1,
        "A": h0, "B": (hd0 + zeta * omega * h0) / omega_d,
    }
    arrays["rows"] = np.column_stack([arrays[name] for name in ROW_FIELDS])  # one segment a row: scalar look-ups
    return arrays


def _locate(arr: dict[str, np.ndarray], t_s: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """The segment of the plan ``arr`` each instant falls in, and the time into it."""
    t = np.asarray(t_s, dtype=np.float64)
    t0 = arr["t0"]
    idx = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, t0.size - 1)
    return idx, np.maximum(t - t0[idx], 0.0)


def _servo_positions(arr: dict[str, np.ndarray], t: np.ndarray, omega: float, zeta: float) -> np.ndarray:
    """``p + e`` of :func:`_eval_segments` at the few instants ``t`` (1-D), in scalar arithmetic: the
    live camera's three instants a frame, where the numpy path's dozen calls on three numbers cost
    ten times more than the numbers (tested against it). No compiled kernel: its first compilation
    would stall the simulated controller's first reply past the serial timeout."""
    omega_d = omega * math.sqrt(1 - zeta * zeta)
    idx = np.searchsorted(arr["t0"], t, side="right") - 1  # at most the last segment; np.clip costs more than the rest
    np.maximum(idx, 0, out=idx)
    out = np.empty(t.size)
    for k, (tk, row) in enumerate(zip(t.tolist(), arr["rows"][idx].tolist())):
        t0, p0, v0, a, c0, c1, big_a, big_b = row
        tau = max(tk - t0, 0.0)
        damped = math.exp(-zeta * omega * tau) * (big_a * math.cos(omega_d * tau) + big_b * math.sin(omega_d * tau))
        out[k] = p0 + v0 * tau + 0.5 * a * tau * tau + c0 + c1 * tau + damped
    return out


def _eval_segments(arr: dict[str, np.ndarray], idx: np.ndarray, tau: np.ndarray, omega: float, zeta: float):
    omega_d = omega * math.sqrt(1 - zeta * zeta)
    a = arr["a"][idx]
    v0 = arr["v0"][idx]
    p = arr["p0"][idx] + v0 * tau + 0.5 * a * tau * tau
    v = v0 + a * tau
    decay = np.exp(-zeta * omega * tau)
    cos, sin = np.cos(omega_d * tau), np.sin(omega_d * tau)
    A, B = arr["A"][idx], arr["B"][idx]
    e = arr["c0"][idx] + arr["c1"][idx] * tau + decay * (A * cos + B * sin)
    ed = arr["c1"][idx] + decay * ((-zeta * omega * A + omega_d * B) * cos + (-zeta * omega * B - omega_d * A) * sin)
    return p, v, e, ed


# ----- trajectories ----------------------------------------------------------------------------


def sweep(start_mm: float, end_mm: float, seconds: float, config: SimStageConfig | None = None,
          dwell_fraction: float = 0.0) -> SimStage:
    """A stage that sweeps ``start → end`` once at constant velocity, filling ``seconds``.

    The velocity is chosen so that the trapezoid (with the configured acceleration) ends
    ``dwell_fraction·seconds`` before the end, after a dwell of the same length at the start; the
    acceleration is raised if the stroke cannot be covered otherwise. This is the calibration-like
    sweep of a scenario: frames cover the stroke uniformly and the motion is slow.
    """
    cfg = SimStageConfig(**vars(config)) if config is not None else SimStageConfig()
    low, high = min(start_mm, end_mm), max(start_mm, end_mm)
    cfg.soft_limits_mm = (min(cfg.soft_limits_mm[0], low), max(cfg.soft_limits_mm[1], high))
    stage = SimStage(cfg, position_mm=start_mm, t_s=0.0)
    t_move = seconds * (1 - 2 * dwell_fraction)
    dist = abs(end_mm - start_mm)
    if dist == 0 or t_move <= 0:
        return stage
    acc = max(cfg.acceleration_mm_s2, 4 * dist / t_move**2 * 1.0001)
    vel = (acc * t_move - math.sqrt(acc * acc * t_move * t_move - 4 * acc * dist)) / 2
    cfg.max_acceleration_mm_s2 = max(cfg.max_acceleration_mm_s2, acc)
    cfg.max_velocity_mm_s = max(cfg.max_velocity_mm_s, vel)
    stage.acceleration_mm_s2 = acc
    stage.velocity_mm_s = vel
    stage.move_to(end_mm, seconds * dwell_fraction)
    return stage


def steps(start_mm: float, end_mm: float, n_steps: int, dwell_s: float,
          config: SimStageConfig | None = None) -> SimStage:
    """Step-and-settle: ``n_steps`` equal moves from start to end, each followed by ``dwell_s`` at rest."""
    cfg = SimStageConfig(**vars(config)) if config is not None else SimStageConfig()
    low, high = min(start_mm, end_mm), max(start_mm, end_mm)
    cfg.soft_limits_mm = (min(cfg.soft_limits_mm[0], low), max(cfg.soft_limits_mm[1], high))
    stage = SimStage(cfg, position_mm=start_mm, t_s=0.0)
    t = dwell_s
    for target in np.linspace(start_mm, end_mm, n_steps + 1)[1:]:
        t = stage.move_to(float(target), t) + dwell_s
    return stage


@dataclass
class FunctionTrajectory:
    """A trajectory given by formulas (no stage limits): e.g. a test's exact motion."""

    position_fn: Callable[[np.ndarray], np.ndarray]
    velocity_fn: Callable[[np.ndarray], np.ndarray]
    peak_acceleration_mm_s2: float | None = None  # the largest acceleration of the formulas, where known

    def position(self, t_s: ArrayLike) -> np.ndarray:
        return np.asarray(self.position_fn(np.asarray(t_s, dtype=np.float64)), dtype=np.float64)

    def velocity(self, t_s: ArrayLike) -> np.ndarray:
        return np.asarray(self.velocity_fn(np.asarray(t_s, dtype=np.float64)), dtype=np.float64)


def constant_velocity(x0_mm: float, v_mm_s: float) -> FunctionTrajectory:
    """``x = x0 + v t``: the exact motion for blur and time-skew tests."""
    return FunctionTrajectory(lambda t: x0_mm + v_mm_s * t, lambda t: np.full_like(t, v_mm_s))


def oscillation(center_mm: float, amplitude_mm: float, frequency_hz: float) -> FunctionTrajectory:
    """``x = c + A sin(2π f t)``: fast reciprocating motion (velocity up to 2π f A)."""
    w = 2 * math.pi * frequency_hz
    return FunctionTrajectory(
        lambda t: center_mm + amplitude_mm * np.sin(w * t),
        lambda t: amplitude_mm * w * np.cos(w * t),
        abs(amplitude_mm) * w * w,
    )


@dataclass
class Vibrating:
    """A trajectory with a structural vibration on top, ``A sin(2π f t + φ)`` (a fan, a pump, the
    servo's own limit cycle): the grating on the stage sees it, the camera averages it over the
    exposure (blur and a position that is not the one at mid-exposure)."""

    base: Trajectory
    amplitude_mm: float
    frequency_hz: float
    phase_rad: float = 0.0

    def position(self, t_s: ArrayLike) -> np.ndarray:
        t = np.asarray(t_s, dtype=np.float64)
        return self.base.position(t) + self.amplitude_mm * np.sin(2 * math.pi * self.frequency_hz * t + self.phase_rad)

    def velocity(self, t_s: ArrayLike) -> np.ndarray:
        t = np.asarray(t_s, dtype=np.float64)
        w = 2 * math.pi * self.frequency_hz
        return self.base.velocity(t) + self.amplitude_mm * w * np.cos(w * t + self.phase_rad)
