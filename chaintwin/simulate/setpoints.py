"""Set-point trajectories for the simulated drive, one value per controller cycle.

A :class:`Setpoints` holds what the drive's set-point generator hands to the
position and speed controllers at every controller cycle: the speed set
point (rad/s, motor side) and the position set point (rad), the cumulative
integral of the speed set point (trapezoidal rule), starting at 0.

The generators below build the usual movement cycles (trapezoid, two-stage
trapezoid, ramp, stairs); :func:`from_arrays` resamples the set points of a
recording to the controller cycle. ``direction=-1`` mirrors a movement (a
backward run): every speed and position is negated.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from chaintwin._types import FloatArray
from chaintwin.errors import ModelError

__all__ = [
    "Setpoints",
    "from_arrays",
    "ramp",
    "stairs",
    "trapezoid",
    "trapezoid2",
]

_DEFAULT_CYCLE_S = 0.001


def _frozen_copy(values: object, name: str) -> FloatArray:
    array = np.array(values, dtype=np.float64, copy=True)
    if array.ndim != 1:
        raise ModelError(f"set points: '{name}' must be a 1-D array, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ModelError(f"set points: '{name}' holds NaN or infinite values; remove them")
    array.flags.writeable = False
    return array


def integrate_speed(speed: FloatArray, cycle_s: float) -> FloatArray:
    """Integrate a speed set point to a position set point (trapezoidal rule).

    Parameters
    ----------
    speed : ndarray of float
        Speed at every controller cycle, rad/s.
    cycle_s : float
        Controller cycle, s.

    Returns
    -------
    ndarray of float
        Position, rad, starting at 0.
    """
    position = np.empty(speed.size, dtype=np.float64)
    if speed.size:
        position[0] = 0.0
        np.cumsum((speed[1:] + speed[:-1]) * (0.5 * cycle_s), out=position[1:])
    return position


@dataclass(frozen=True, eq=False, slots=True)
class Setpoints:
    """Speed and position set points at every controller cycle.

    Parameters
    ----------
    cycle_s : float
        Controller cycle, s.
    speed : ndarray of float
        Speed set point at every cycle, rad/s (motor side).
    position : ndarray of float
        Position set point at every cycle, rad; the cumulative integral of
        ``speed``, starting at 0.

    Raises
    ------
    ModelError
        When the arrays are not 1-D, differ in length, hold fewer than two
        values or non-finite values, or the cycle is not positive.

    Notes
    -----
    The arrays are copied and made read-only.
    """

    cycle_s: float
    speed: FloatArray
    position: FloatArray
    _time: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cycle_s) and self.cycle_s > 0.0):
            raise ModelError(f"set points: the cycle must be a positive time, got {self.cycle_s}")
        speed = _frozen_copy(self.speed, "speed")
        position = _frozen_copy(self.position, "position")
        if speed.size != position.size:
            raise ModelError(
                f"set points: speed has {speed.size} values but position {position.size}; "
                "give one of each per controller cycle"
            )
        if speed.size < 2:
            raise ModelError("set points: at least two controller cycles are needed")
        object.__setattr__(self, "speed", speed)
        object.__setattr__(self, "position", position)
        time = np.arange(speed.size, dtype=np.float64) * self.cycle_s
        time.flags.writeable = False
        object.__setattr__(self, "_time", time)

    def __len__(self) -> int:
        return int(self.speed.size)

    @property
    def time(self) -> FloatArray:
        """Time of every cycle, ``k·cycle_s``, s (read-only)."""
        return self._time

    @property
    def duration_s(self) -> float:
        """Time from the first to the last cycle, ``(n - 1)·cycle_s``, s."""
        return float((self.speed.size - 1) * self.cycle_s)

    def mirrored(self) -> Setpoints:
        """The same movement backwards (speed and position negated)."""
        return Setpoints(self.cycle_s, -self.speed, -self.position)


# ------------------------------------------------------------------ helpers
def _check_positive(name: str, value: float, *, allow_zero: bool = False) -> None:
    ok = math.isfinite(value) and (value >= 0.0 if allow_zero else value > 0.0)
    if not ok:
        need = "zero or positive" if allow_zero else "positive"
        raise ModelError(f"set points: '{name}' must be {need}, got {value}")


def _check_direction(direction: int) -> None:
    if direction not in (1, -1):
        raise ModelError(f"set points: 'direction' must be 1 or -1, got {direction}")


def _from_knots(
    knots: list[tuple[float, float]],
    *,
    tail_s: float,
    cycle_s: float,
    direction: int,
) -> Setpoints:
    """Sample a piecewise-linear speed through (time, speed) knots at the cycle."""
    kept: list[tuple[float, float]] = []
    for t_knot, v_knot in knots:  # zero-length segments join equal speeds: drop them
        if kept and t_knot <= kept[-1][0]:
            kept[-1] = (kept[-1][0], v_knot)
        else:
            kept.append((t_knot, v_knot))
    times = np.array([t for t, _ in kept], dtype=np.float64)
    values = np.array([v for _, v in kept], dtype=np.float64)
    end = float(times[-1]) + tail_s
    n = max(2, round(end / cycle_s) + 1)
    t = np.arange(n, dtype=np.float64) * cycle_s
    speed = np.interp(t, times, values) * float(direction)
    return Setpoints(cycle_s, speed, integrate_speed(speed, cycle_s))


def _common_checks(lead_s: float, tail_s: float, cycle_s: float, direction: int) -> None:
    _check_positive("lead_s", lead_s, allow_zero=True)
    _check_positive("tail_s", tail_s, allow_zero=True)
    _check_positive("cycle_s", cycle_s)
    _check_direction(direction)


# --------------------------------------------------------------- generators
def trapezoid(
    *,
    speed_rad_s: float,
    accel_rad_s2: float,
    hold_s: float,
    decel_rad_s2: float | None = None,
    direction: int = 1,
    lead_s: float = 0.1,
    tail_s: float = 0.4,
    cycle_s: float = _DEFAULT_CYCLE_S,
) -> Setpoints:
    """A trapezoidal movement: standstill, ramp up, hold, ramp down, standstill.

    Parameters
    ----------
    speed_rad_s : float
        Plateau speed, rad/s (motor side), ≥ 0.
    accel_rad_s2 : float
        Acceleration of the ramp up, rad/s², > 0.
    hold_s : float
        Time at the plateau speed, s, ≥ 0.
    decel_rad_s2 : float, optional
        Deceleration of the ramp down, rad/s², > 0 (default: ``accel_rad_s2``).
    direction : {1, -1}
        -1 mirrors the movement (backward run).
    lead_s, tail_s : float
        Standstill before and after the movement, s.
    cycle_s : float
        Controller cycle, s.

    Returns
    -------
    Setpoints

    Raises
    ------
    ModelError
        For a negative speed or time, a non-positive acceleration or a
        direction other than ±1.
    """
    decel = accel_rad_s2 if decel_rad_s2 is None else decel_rad_s2
    _check_positive("speed_rad_s", speed_rad_s, allow_zero=True)
    _check_positive("accel_rad_s2", accel_rad_s2)
    _check_positive("decel_rad_s2", decel)
    _check_positive("hold_s", hold_s, allow_zero=True)
    _common_checks(lead_s, tail_s, cycle_s, direction)
    t_up = speed_rad_s / accel_rad_s2
    t_down = speed_rad_s / decel
    knots = [(0.0, 0.0), (lead_s, 0.0), (lead_s + t_up, speed_rad_s)]
    knots.append((knots[-1][0] + hold_s, speed_rad_s))
    knots.append((knots[-1][0] + t_down, 0.0))
    return _from_knots(knots, tail_s=tail_s, cycle_s=cycle_s, direction=direction)


def trapezoid2(
    *,
    speed_rad_s: float,
    accel1_rad_s2: float,
    accel2_rad_s2: float,
    switch_fraction: float = 0.5,
    hold_s: float,
    direction: int = 1,
    lead_s: float = 0.1,
    tail_s: float = 0.4,
    cycle_s: float = _DEFAULT_CYCLE_S,
) -> Setpoints:
    """A trapezoid with two accelerations, mirrored on the way down.

    The speed rises at ``accel1_rad_s2`` up to ``switch_fraction·speed``,
    then at ``accel2_rad_s2`` to the plateau; on the way down it falls at
    ``accel2_rad_s2`` to ``switch_fraction·speed``, then at ``accel1_rad_s2``
    to standstill.

    Parameters
    ----------
    speed_rad_s : float
        Plateau speed, rad/s, ≥ 0.
    accel1_rad_s2, accel2_rad_s2 : float
        First and second acceleration, rad/s², > 0.
    switch_fraction : float
        Fraction of the plateau speed where the acceleration changes, in [0, 1].
    hold_s : float
        Time at the plateau speed, s.
    direction : {1, -1}
        -1 mirrors the movement.
    lead_s, tail_s : float
        Standstill before and after, s.
    cycle_s : float
        Controller cycle, s.

    Returns
    -------
    Setpoints

    Raises
    ------
    ModelError
        For invalid numbers (see :func:`trapezoid`) or a switch fraction
        outside [0, 1].
    """
    _check_positive("speed_rad_s", speed_rad_s, allow_zero=True)
    _check_positive("accel1_rad_s2", accel1_rad_s2)
    _check_positive("accel2_rad_s2", accel2_rad_s2)
    _check_positive("hold_s", hold_s, allow_zero=True)
    if not (0.0 <= switch_fraction <= 1.0):
        raise ModelError(f"set points: 'switch_fraction' must lie in [0, 1], got {switch_fraction}")
    _common_checks(lead_s, tail_s, cycle_s, direction)
    v1 = switch_fraction * speed_rad_s
    t1 = v1 / accel1_rad_s2
    t2 = (speed_rad_s - v1) / accel2_rad_s2
    knots = [(0.0, 0.0), (lead_s, 0.0), (lead_s + t1, v1)]
    knots.append((knots[-1][0] + t2, speed_rad_s))
    knots.append((knots[-1][0] + hold_s, speed_rad_s))
    knots.append((knots[-1][0] + t2, v1))
    knots.append((knots[-1][0] + t1, 0.0))
    return _from_knots(knots, tail_s=tail_s, cycle_s=cycle_s, direction=direction)


def ramp(
    *,
    speed_rad_s: float,
    ramp_s: float,
    hold_s: float,
    direction: int = 1,
    lead_s: float = 0.1,
    tail_s: float = 0.4,
    cycle_s: float = _DEFAULT_CYCLE_S,
) -> Setpoints:
    """Ramp up in ``ramp_s``, hold, ramp down in ``ramp_s``.

    Parameters
    ----------
    speed_rad_s : float
        Plateau speed, rad/s, ≥ 0.
    ramp_s : float
        Duration of each ramp, s, > 0.
    hold_s : float
        Time at the plateau, s.
    direction : {1, -1}
        -1 mirrors the movement.
    lead_s, tail_s : float
        Standstill before and after, s.
    cycle_s : float
        Controller cycle, s.

    Returns
    -------
    Setpoints

    Raises
    ------
    ModelError
        For invalid numbers.
    """
    _check_positive("speed_rad_s", speed_rad_s, allow_zero=True)
    _check_positive("ramp_s", ramp_s)
    _check_positive("hold_s", hold_s, allow_zero=True)
    _common_checks(lead_s, tail_s, cycle_s, direction)
    knots = [(0.0, 0.0), (lead_s, 0.0), (lead_s + ramp_s, speed_rad_s)]
    knots.append((knots[-1][0] + hold_s, speed_rad_s))
    knots.append((knots[-1][0] + ramp_s, 0.0))
    return _from_knots(knots, tail_s=tail_s, cycle_s=cycle_s, direction=direction)


def stairs(
    *,
    speeds_rad_s: Sequence[float],
    step_s: float,
    accel_rad_s2: float,
    direction: int = 1,
    lead_s: float = 0.1,
    tail_s: float = 0.4,
    cycle_s: float = _DEFAULT_CYCLE_S,
) -> Setpoints:
    """Successive speed plateaus joined by ramps, back to standstill at the end.

    Parameters
    ----------
    speeds_rad_s : sequence of float
        Plateau speeds in order, rad/s (any sign; a sign change passes
        through zero on the ramp).
    step_s : float
        Time at each plateau (ramps excluded), s.
    accel_rad_s2 : float
        Magnitude of the acceleration on every ramp, rad/s², > 0.
    direction : {1, -1}
        -1 mirrors the movement.
    lead_s, tail_s : float
        Standstill before and after, s.
    cycle_s : float
        Controller cycle, s.

    Returns
    -------
    Setpoints

    Raises
    ------
    ModelError
        For an empty speed list or invalid numbers.
    """
    levels = [float(v) for v in speeds_rad_s]
    if not levels or not all(math.isfinite(v) for v in levels):
        raise ModelError("set points: 'speeds_rad_s' must hold at least one finite speed")
    _check_positive("step_s", step_s, allow_zero=True)
    _check_positive("accel_rad_s2", accel_rad_s2)
    _common_checks(lead_s, tail_s, cycle_s, direction)
    knots = [(0.0, 0.0), (lead_s, 0.0)]
    previous = 0.0
    for level in levels:
        t = knots[-1][0] + abs(level - previous) / accel_rad_s2
        knots += [(t, level), (t + step_s, level)]
        previous = level
    knots.append((knots[-1][0] + abs(previous) / accel_rad_s2, 0.0))
    return _from_knots(knots, tail_s=tail_s, cycle_s=cycle_s, direction=direction)


def from_arrays(
    time_s: npt.ArrayLike,
    speed_setpoint: npt.ArrayLike,
    position_setpoint: npt.ArrayLike | None = None,
    *,
    cycle_s: float = _DEFAULT_CYCLE_S,
) -> Setpoints:
    """Resample a recording's set points to the controller cycle.

    Parameters
    ----------
    time_s : array_like of float
        Sample times of the recording, s, strictly increasing (drive scopes
        sample every 1-12 ms).
    speed_setpoint : array_like of float
        Speed set point at those times, rad/s.
    position_setpoint : array_like of float, optional
        Position set point at those times, rad (any offset). When given it is
        interpolated and shifted to start at 0; otherwise the resampled
        speed set point is integrated (trapezoidal rule).
    cycle_s : float
        Controller cycle to resample to, s.

    Returns
    -------
    Setpoints
        Cycle ``k`` is at ``time_s[0] + k·cycle_s``, up to the last sample.

    Raises
    ------
    ModelError
        For arrays of different lengths, fewer than two samples, time not
        strictly increasing, or non-finite values.
    """
    _check_positive("cycle_s", cycle_s)
    t = np.asarray(time_s, dtype=np.float64)
    v = np.asarray(speed_setpoint, dtype=np.float64)
    if t.ndim != 1 or v.shape != t.shape:
        raise ModelError(
            f"set points: time ({t.shape}) and speed set point ({v.shape}) must be 1-D "
            "arrays of the same length"
        )
    if t.size < 2:
        raise ModelError("set points: at least two samples are needed")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        raise ModelError("set points: time or speed set point holds NaN or infinite values")
    if np.any(np.diff(t) <= 0.0):
        raise ModelError("set points: time must be strictly increasing; sort the samples")
    n = max(2, math.floor((t[-1] - t[0]) / cycle_s + 1e-9) + 1)
    grid = t[0] + np.arange(n, dtype=np.float64) * cycle_s
    speed = np.interp(grid, t, v)
    if position_setpoint is None:
        position = integrate_speed(speed, cycle_s)
    else:
        p = np.asarray(position_setpoint, dtype=np.float64)
        if p.shape != t.shape:
            raise ModelError(
                f"set points: position set point has shape {p.shape}, time {t.shape}; "
                "give one value per sample"
            )
        if not np.all(np.isfinite(p)):
            raise ModelError("set points: position set point holds NaN or infinite values")
        position = np.interp(grid, t, p)
        position -= position[0]
    return Setpoints(cycle_s, speed, position)
