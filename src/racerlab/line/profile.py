"""Speed profile along a path under the simulator's car limits, and the lap times it gives.

The limits are exactly the ones `racerlab.sim.car.advance` applies, so that a driver that follows
the path can reach the predicted time:

* lateral: the grip caps v²·|κ| at `grip_mps2`, and the steering can bend the path at most as much as full lock
  does at that speed (`yaw_gain_at(v)` · tan 30° / wheelbase: the car slides more the faster it goes; through the
  tyres' saturation, `CarParams.saturated`), so a point
  of curvature κ allows the fastest v at which both hold;
* speed cap: the car settles at `top_speed()` (the command clip and the wheels' cap, times the ground factor);
* longitudinal: speed follows the command with a first-order lag `speed_tau_s`, bounded by
  `accel_mps2` (falling with speed: `accel_limit`) and `brake_mps2`. With the command at the cap the car can gain
  at most
  (cap - v)/τ per second, so the usable acceleration is min(accel, (cap - v)/τ); the same holds
  for braking toward the minimum speed.

A forward pass (accelerate as hard as allowed) and a backward pass (brake as late as allowed)
over the lateral limit give the fastest speed at every point (the classic "ggv" method with a
velocity-dependent acceleration and no friction circle, because the simulator has none).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from racerlab.spec import STEP_S, CarParams

SUBSTEPS = 4  # integration steps per path segment in the passes
BRAKE_FLOOR_MPS = 0.05  # braking near the slowest speed is counted as from this far above it (see `_brake`)


class Profile(NamedTuple):
    speed: np.ndarray  # (M,) m/s at each point
    time: np.ndarray  # (M + 1,) s from point 0 to each point, last = back at point 0 (loops) or the end
    lap_time: float  # time[-1]


def max_curvature(v, car: CarParams) -> np.ndarray:
    """The tightest path curvature (1/m) the car can hold at ground speed `v`: full lock through the yaw gain and
    the tyres' saturation, and the grip."""
    v = np.asarray(v, dtype=np.float64)
    lock = car.max_steer_deg + abs(car.steer_offset_deg)  # the side the wheels' offset turns more: still a bound
    tan_d = car.yaw_gain_at(v) * math.tan(math.radians(lock))
    steer = car.saturated(tan_d / (car.wheelbase_m * np.sqrt(1.0 + 0.25 * tan_d * tan_d)), v)
    with np.errstate(divide="ignore"):
        grip = car.grip_mps2 / (v * v)
    return np.minimum(steer, grip)


def lateral_limit(curvature: np.ndarray, car: CarParams) -> np.ndarray:
    """Fastest speed at which the car holds each curvature (capped at the top speed; never below the slowest
    speed it drives at), m/s. `max_curvature` falls with speed, so a bisection finds it. A bend tighter than full
    lock holds at any speed (a kink of a shortest path) is taken as the car's tightest circle, which is what it
    drives there."""
    k = np.minimum(np.abs(np.asarray(curvature, dtype=np.float64)), max_curvature(1e-9, car))
    top = car.top_speed()
    lo = np.zeros_like(k)
    hi = np.full_like(k, top)
    for _ in range(48):
        mid = 0.5 * (lo + hi)
        ok = k <= max_curvature(mid, car)
        lo = np.where(ok, mid, lo)
        hi = np.where(ok, hi, mid)
    v = np.where(k <= max_curvature(top, car), top, lo)
    return np.maximum(v, car.min_speed_mps * car.ground_factor)


def _accel(v: float, car: CarParams) -> float:
    top = car.top_speed()
    a = float(car.accel_limit(v))  # traction, falling with speed where the car's acceleration fades
    return min(a, (top - v) / car.speed_tau_s) if car.speed_tau_s > 0 else a


def _brake(v: float, car: CarParams) -> float:
    """The braking rate at `v`: toward the slowest command's speed through the lag, but never slower than over the
    last BRAKE_FLOOR_MPS above it (the lag only approaches that speed, so a bend that must be driven at it, a kink
    tighter than a sliding car's full lock at any speed, would otherwise hold the whole lap there)."""
    low = car.min_speed_mps * car.ground_factor
    return (min(car.brake_mps2, max(v - low, BRAKE_FLOOR_MPS) / car.speed_tau_s) if car.speed_tau_s > 0
            else car.brake_mps2)


def _gain(v: float, ds: float, rate, car: CarParams) -> float:
    """Speed after `ds` metres starting at `v` while changing speed at `rate(v)` m/s² (midpoint rule)."""
    h = ds / SUBSTEPS
    for _ in range(SUBSTEPS):
        a = max(rate(v, car), 0.0)
        v_half = math.sqrt(v * v + a * h)
        v = math.sqrt(v * v + 2.0 * max(rate(v_half, car), 0.0) * h)
    return v


def _pass(limit: np.ndarray, ds: np.ndarray, order: np.ndarray, rate, car: CarParams, v_start: float) -> np.ndarray:
    """One pass over `order` (indices): each point at most what the previous one reaches at `rate`."""
    v = limit.copy()
    v[order[0]] = min(v[order[0]], v_start)
    prev = order[0]
    for i, seg in zip(order[1:].tolist(), ds.tolist(), strict=True):
        v[i] = min(v[i], _gain(float(v[prev]), seg, rate, car))
        prev = i
    return v


def speed_profile(curvature, seg_lengths, car: CarParams | None = None, closed: bool = True,
                  v_start: float | None = None) -> Profile:
    """Fastest speed at each of M path points from their curvature and segment lengths.

    `seg_lengths[i]` is the length from point i to point i+1 (for a loop the last one closes it,
    so M of them; M-1 for an open path). For a loop without `v_start` the profile is periodic (a
    flying lap); with `v_start` (0 for a standing start) point 0 starts at that speed, and a loop
    ends back at point 0 at the flying lap's speed there.
    """
    car = car or CarParams()
    k = np.asarray(curvature, dtype=np.float64)
    ds = np.asarray(seg_lengths, dtype=np.float64)
    m = len(k)
    limit = lateral_limit(k, car)
    if closed:
        i0 = int(np.argmin(limit))  # the slowest corner: its speed is known, start both passes there
        order = np.mod(np.arange(i0, i0 + m + 1), m)
        v = _pass(limit, ds[order[:-1]], order, _accel, car, limit[i0])
        v = _pass(v, ds[order[::-1][1:]], order[::-1], _brake, car, v[i0])
        if v_start is None:
            return _timed(v, np.append(v[1:], v[0]), ds)
        limit = np.append(v, v[0])  # the flying lap already holds every braking constraint
    else:
        limit = _pass(limit, ds[::-1], np.arange(m)[::-1], _brake, car, limit[-1])
    v = _pass(limit, ds, np.arange(len(limit)), _accel, car, math.inf if v_start is None else v_start)
    return _timed(v[:m], v[1:], ds)


def _timed(v: np.ndarray, v_next: np.ndarray, ds: np.ndarray) -> Profile:
    dt = 2.0 * ds / np.maximum(v[: len(ds)] + v_next[: len(ds)], 1e-9)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return Profile(v, t, float(t[-1]))


def timer_lap_time(drive_time_s: float, step_s: float = STEP_S) -> float:
    """What the simulator's lap timer shows for a lap the car drives in `drive_time_s` from a standstill.

    The episode's first step is the prepare step (car held), and a step judges the pose the
    previous step left, so the lap is seen one step after the line is crossed: the timer counts
    2 steps more than the ceil(drive / step) steps of driving.
    """
    return (2 + math.ceil(drive_time_s / step_s - 1e-9)) * step_s
