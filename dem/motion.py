"""Prescribed wall motions: where a wall is, how fast it moves and how it accelerates at time t.

A motion is plain data with a numeric ``code`` row so that the step kernel can evaluate it at every
step without calling Python (``motion_row`` / ``evaluate``). This module must not know about
contacts or bodies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from dem.conf import JIT_FLAGS, STEP_FLAGS
from dem.frames import norm

# Layout of a motion row: kind, direction (3), amplitude, frequency, start_time, ramp_time, phase.
# A lift uses the amplitude slot for its distance and the frequency slot for its speed, so the
# kernel's neighbour-list margin (twice the amplitude) covers the whole travel.
MOTION_ROW = 9
_STATIC = 0.0
_SINE = 1.0
_LIFT = 2.0


class MotionError(ValueError):
    """A motion's parameters are not usable; the message names the field."""


@dataclass(frozen=True)
class SinusoidalTranslation:
    """d(t) = A s(tau) [sin(2 pi f tau + phase) - sin(phase)] u for tau = t - start_time >= 0,
    zero before (the offset keeps the wall where it was when the motion starts).

    ``amplitude`` A is the peak displacement (m) along the unit vector u (``direction``,
    normalised here). The optional ramp s(tau) = (1 - cos(pi tau / ramp_time)) / 2 grows the
    amplitude smoothly from 0 to A over ``ramp_time`` so that velocity and acceleration start
    without a jump (a sudden start kicks resting items). ``phase = -pi/2`` instead starts at the
    lowest point with zero velocity, d = A (1 - cos(2 pi f tau)) u.
    """

    direction: tuple[float, float, float]
    amplitude: float
    frequency: float
    start_time: float = 0.0
    ramp_time: float = 0.0
    phase: float = 0.0

    def __post_init__(self) -> None:
        direction = np.asarray(self.direction, dtype=np.float64).reshape(-1)
        if direction.shape != (3,) or not np.all(np.isfinite(direction)) or not np.any(direction):
            raise MotionError(f"direction must be a non-zero 3-vector, got {self.direction!r}")
        object.__setattr__(self, "direction", tuple(float(v) for v in direction / norm(direction)))
        if not math.isfinite(self.phase):
            raise MotionError(f"phase must be a finite angle in radians, got {self.phase!r}")
        for name in ("amplitude", "frequency", "start_time", "ramp_time"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise MotionError(f"{name} must be a finite number >= 0, got {value!r}")

    def row(self) -> np.ndarray:
        return np.array(
            [
                _SINE,
                *self.direction,
                self.amplitude,
                self.frequency,
                self.start_time,
                self.ramp_time,
                self.phase,
            ]
        )

    def displacement(self, t: float) -> np.ndarray:
        return evaluate(self.row(), t)[0]

    def velocity(self, t: float) -> np.ndarray:
        return evaluate(self.row(), t)[1]


@dataclass(frozen=True)
class LinearLift:
    """d(t) = min(v tau, L) u for tau = t - start_time >= 0, zero before: the wall starts moving
    at ``speed`` v along the unit vector u at ``start_time`` and stops after ``distance`` L.

    This is how an angle-of-repose cylinder is lifted off its plate (a constant lifting speed,
    as in the test rigs); the speed jumps at both ends, which a kinematic wall may do.
    """

    direction: tuple[float, float, float]
    distance: float
    speed: float
    start_time: float = 0.0

    def __post_init__(self) -> None:
        direction = np.asarray(self.direction, dtype=np.float64).reshape(-1)
        if direction.shape != (3,) or not np.all(np.isfinite(direction)) or not np.any(direction):
            raise MotionError(f"direction must be a non-zero 3-vector, got {self.direction!r}")
        object.__setattr__(self, "direction", tuple(float(v) for v in direction / norm(direction)))
        for name in ("distance", "start_time"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise MotionError(f"{name} must be a finite number >= 0, got {value!r}")
        if not math.isfinite(self.speed) or self.speed <= 0:
            raise MotionError(f"speed must be a finite number > 0, got {self.speed!r}")

    def row(self) -> np.ndarray:
        return np.array([_LIFT, *self.direction, self.distance, self.speed, self.start_time, 0.0, 0.0])

    def displacement(self, t: float) -> np.ndarray:
        return evaluate(self.row(), t)[0]

    def velocity(self, t: float) -> np.ndarray:
        return evaluate(self.row(), t)[1]

    @property
    def end_time(self) -> float:
        return self.start_time + self.distance / self.speed


Motion = SinusoidalTranslation | LinearLift


def motion_row(motion: Motion | None) -> np.ndarray:
    """The kernel's row for a motion; ``None`` is a wall at rest."""
    if motion is None:
        return np.zeros(MOTION_ROW)
    return motion.row()


@numba.njit(**JIT_FLAGS)
def evaluate(row, t):
    """(displacement, velocity, acceleration) of a motion row at time t, each (3,)."""
    d, v, a = _scalar_state(row, t)
    disp = np.empty(3)
    vel = np.empty(3)
    acc = np.empty(3)
    for k in range(3):
        disp[k] = d * row[1 + k]
        vel[k] = v * row[1 + k]
        acc[k] = a * row[1 + k]
    return disp, vel, acc


@numba.njit(**STEP_FLAGS)
def evaluate_into(row, t, disp, vel):
    """Displacement and velocity of a motion row at time t written into ``disp`` and ``vel``;
    the step kernel's allocation-free form of ``evaluate``."""
    d, v, _ = _scalar_state(row, t)
    for k in range(3):
        disp[k] = d * row[1 + k]
        vel[k] = v * row[1 + k]


@numba.njit(**JIT_FLAGS)
def _scalar_state(row, t):
    if row[0] == _STATIC:
        return 0.0, 0.0, 0.0
    if row[0] == _LIFT:
        tau = t - row[6]
        if tau <= 0.0:
            return 0.0, 0.0, 0.0
        if tau * row[5] >= row[4]:
            return row[4], 0.0, 0.0
        return tau * row[5], row[5], 0.0
    amp, freq, start, ramp = row[4], row[5], row[6], row[7]
    tau = t - start
    if tau <= 0.0:
        return 0.0, 0.0, 0.0
    omega = 2.0 * math.pi * freq
    sin_w = math.sin(omega * tau + row[8])
    cos_w = math.cos(omega * tau + row[8])
    offset = math.sin(row[8])
    s, ds, dds = 1.0, 0.0, 0.0
    if ramp > 0.0 and tau < ramp:
        k = math.pi / ramp
        s = 0.5 * (1.0 - math.cos(k * tau))
        ds = 0.5 * k * math.sin(k * tau)
        dds = 0.5 * k * k * math.cos(k * tau)
    d = amp * s * (sin_w - offset)
    v = amp * (ds * (sin_w - offset) + s * omega * cos_w)
    a = amp * (dds * (sin_w - offset) + 2.0 * ds * omega * cos_w - s * omega * omega * sin_w)
    return d, v, a
