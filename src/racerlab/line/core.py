"""`RacingLine`, `racing_line(track, ...)` and `theoretical_limit(track, ...)`: solved lines with their speed
profile and lap times.

A line is the path of the car's base point (midway between the axles, the point the simulator moves as a
kinematic bicycle). Two kinds, for two uses:

* the **racing line** (`racing_line`, kind "line"): kept `clearance_m` = half the wheel track + a wheel radius +
  `margin` from both borders, so the whole car stays on the road with `margin` to spare: the line a reward
  function should follow;
* the **limit** (`theoretical_limit`, kind "limit"): the fastest lap the simulator's rules allow. The simulator
  calls a car off track only when none of its four wheel centres is on the road (facts §2), so a car whose
  base point is up to `offtrack_overhang` (the half-diagonal of the wheel centres, 0.115 m) outside a border
  can still be on track, whatever its heading: the limit lets the base point go that far out, and is the
  fastest of the minimum-curvature line, the shortest line and mixes of the two there: a lower bound for laps
  on exact 1/15 s steps (up to the path, which is not an exact minimum-time one).

Its speed is the fastest the simulator's car (`racerlab.spec.CarParams`) can drive it: grip and the steering's
tightest bend in the corners, acceleration and braking in between (see `racerlab.line.profile`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from racerlab.errors import TrackError
from racerlab.line import geometry as G
from racerlab.line import profile as P
from racerlab.line.solve import METHODS, solve
from racerlab.spec import MODEL_POINT_AHEAD_M, WHEELBASE_M, CarParams, car_params
from racerlab.track import Track
from racerlab.track import load as load_track

WHEEL_RADIUS_M = 0.036  # a wheel reaches this far beyond its centre; the car's width is track_m + 2 × this
DEFAULT_MARGIN_M = 0.1
LIMIT_BLENDS = (1e-4, 1e-3, 3e-3, 1e-2)  # shortest-path weights of the mixed lines the limit tries too


def car_clearance(car: CarParams | None = None, margin: float = DEFAULT_MARGIN_M) -> float:
    """How far the base point must stay from a border so the whole car keeps `margin` to it, m."""
    car = car or CarParams()
    return 0.5 * car.track_m + WHEEL_RADIUS_M + margin


def offtrack_overhang(car: CarParams | None = None) -> float:
    """How far outside a border the base point can be while a wheel centre is still on the road, m: the distance
    from the base point to the farthest wheel centre (the car may stand at any angle to the border)."""
    car = car or CarParams()
    return float(np.hypot(0.5 * car.wheelbase_m, 0.5 * car.track_m))


def min_margin(car: CarParams | None = None) -> float:
    """The smallest `margin` the simulator's off-track rule allows (negative: the base point `offtrack_overhang`
    outside a border), m."""
    return -offtrack_overhang(car) - car_clearance(car, 0.0)


def steering_for_curvature(curvature, wheelbase_m: float = WHEELBASE_M, gain=1.0) -> np.ndarray:
    """Steering angle (°, + = left) that makes the base point follow `curvature` (1/m).

    The inverse of the simulator's bicycle about the mid-wheelbase point: κ = cos β · g · tan δ / L
    with sin β = κ·L/2, so tan δ = κ·L / (g · cos β); `gain` g is the car's yaw gain at its speed
    (`CarParams.yaw_gain_at`; 1 for the kinematic bicycle).
    """
    k = np.asarray(curvature, dtype=np.float64)
    half = np.clip(0.5 * k * wheelbase_m, -0.999, 0.999)
    return np.degrees(np.arctan(k * wheelbase_m / np.sqrt(1.0 - half**2) / gain))


@dataclass(frozen=True, eq=False)
class RacingLine:
    """A racing line on a track with the fastest speed the car can drive it at.

    `xy`, `speed`, `curvature`, `time` have one row per point (M, about every 0.1 m), in driving
    order, starting abreast of the start line; the loop closes from the last point back to the
    first. `speed` and `time` are those of a flying lap (the car already at speed), which is what a
    reward function should aim at; `lap_time` is the lap as the simulator's timer shows it from a
    standing start at the start line (prepare step included), comparable with AWS lap times;
    `flying_lap_time` is the lap once rolling. `kind` is "line" (a racing line: the whole car `margin_m`
    inside the borders) or "limit" (the theoretical limit: the base point may be `-clearance_m` outside them, as
    far as the simulator's off-track rule allows; `margin_m` is then negative).
    """

    track_name: str
    method: str
    margin_m: float
    xy: np.ndarray  # (M, 2) m
    speed: np.ndarray  # (M,) m/s, flying lap
    curvature: np.ndarray  # (M,) 1/m, + = turning left
    time: np.ndarray  # (M,) s from point 0 on a flying lap
    lap_time: float  # s, standing start, as the simulator times it
    flying_lap_time: float  # s
    start_speed: np.ndarray  # (M,) m/s on the first lap from a standstill at point 0
    car: CarParams = field(default_factory=CarParams)
    clearance_m: float = 0.0
    iterations: int = 0
    converged: bool = True
    solve_s: float = 0.0
    kind: str = "line"

    @property
    def s(self) -> np.ndarray:
        """Arc length of each point from point 0, m."""
        return G.arc_length(self.xy)[:-1]

    @property
    def length(self) -> float:
        return float(G.arc_length(self.xy)[-1])

    @property
    def heading_deg(self) -> np.ndarray:
        """Driving direction at each point, degrees as the reward params give `heading`."""
        t = G.tangents(self.xy)
        return np.degrees(np.arctan2(t[:, 1], t[:, 0]))

    @property
    def steering_deg(self) -> np.ndarray:
        """Steering angle each point needs at the line's speed (the car's wheelbase and yaw gain), ° (+ = left)."""
        kappa = self.car.unsaturated(self.curvature, self.speed)
        wheels = steering_for_curvature(kappa, self.car.wheelbase_m, self.car.yaw_gain_at(self.speed))
        return wheels - self.car.steer_offset_deg  # the command: the wheels point `steer_offset_deg` left of it

    def summary(self) -> dict:
        """The headline numbers, JSON-ready."""
        return {"track": self.track_name, "kind": self.kind, "method": self.method,
                "margin_m": round(self.margin_m, 4), "clearance_m": round(self.clearance_m, 4),
                "points": int(len(self.xy)), "length_m": round(self.length, 3),
                "lap_time_s": round(self.lap_time, 3), "flying_lap_time_s": round(self.flying_lap_time, 3),
                "min_speed_mps": round(float(self.speed.min()), 3),
                "max_speed_mps": round(float(self.speed.max()), 3),
                "iterations": self.iterations, "converged": self.converged, "solve_s": round(self.solve_s, 3)}

    def __repr__(self) -> str:
        return (f"RacingLine({self.track_name!r}, {self.kind}, {self.method}, margin {self.margin_m:g} m, "
                f"{len(self.xy)} points, "
                f"{self.length:.2f} m, lap {self.lap_time:.3f} s, flying {self.flying_lap_time:.3f} s)")


def racing_line(track: Track | str, margin: float = DEFAULT_MARGIN_M, method: str = "mincurv",
                car: CarParams | str | None = None, step_m: float = 0.1, blend: float | None = None) -> RacingLine:
    """Solve the racing line of `track` (a `Track` or a track name/path) and its speed profile.

    `method` is "mincurv" (minimum curvature: the fastest line in practice) or "shortest"
    (shortest path); `margin` (m) is kept between the car's wheels and each border (negative: they may hang over
    it, at most as far as the off-track rule allows, `min_margin`); `car` sets
    the limits: a `CarParams` or a simulator's name (its version-5 car, `spec.car_params`; default `CarParams()`,
    the droa simulator's car); `blend` (0-1), if given, solves for that mix of the two methods' objectives
    instead (`line.solve`; the line's method reads e.g. "blend 0.001"). Raises `TrackError` for a loop-less
    (open) track or where the road is too narrow for the car and the margin.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    car = car_params(car) if isinstance(car, str) else car or CarParams()
    if margin < min_margin(car) - 1e-12:
        raise ValueError(f"margin must be >= {min_margin(car):.4f} m (the off-track rule's overhang), got {margin}")
    t = track if isinstance(track, Track) else load_track(track)
    if not t.closed:
        raise TrackError(f"{t.name}: a racing line needs a closed loop; this track is open")
    clearance = car_clearance(car, margin)
    t0 = time.perf_counter()
    sol = solve(t, clearance, method, step_m=step_m, blend=blend)
    line = _with_profile(t, sol, method if blend is None else f"blend {blend:g}", margin, car, clearance)
    return replace(line, solve_s=time.perf_counter() - t0)


def theoretical_limit(track: Track | str, car: CarParams | str | None = None, step_m: float = 0.1) -> RacingLine:
    """The fastest lap the simulator allows on `track` for `car` (as in `racing_line`), as a `RacingLine` of kind
    "limit": the fastest of the minimum-curvature line, the shortest line and mixes of the two (`LIMIT_BLENDS`)
    with the base point allowed `offtrack_overhang` outside the borders (a wheel centre still on the road), at the
    profile's speed.

    It is a lower bound under the simulator's rules with exact steps as far as the path goes: the profile holds
    the car's own grip, steering, top speed and traction (`line.profile`) and ignores its delay and lags, and no
    legal pose has the base point farther out. None of the lines is the exact minimum-time path, so a cleverer
    path could still be a little faster (the mixes gained up to 0.13 s over the better pure method on
    reInvent2019_track).
    """
    car = car_params(car) if isinstance(car, str) else car or CarParams()
    t0 = time.perf_counter()
    best = fastest_line(track, min_margin(car), car, step_m)
    return replace(best, kind="limit", solve_s=time.perf_counter() - t0)


def fastest_line(track: Track | str, margin: float = DEFAULT_MARGIN_M, car: CarParams | str | None = None,
                 step_m: float = 0.1) -> RacingLine:
    """The fastest of the paths `theoretical_limit` tries (minimum curvature, shortest, their mixes
    `LIMIT_BLENDS`) with `margin` kept to the borders, as in `racing_line`: the limit's kind of path at a margin
    a racer chooses (the `racing_line` reward template follows it)."""
    t = track if isinstance(track, Track) else load_track(track)
    car = car_params(car) if isinstance(car, str) else car or CarParams()
    lines = [racing_line(t, margin, method, car, step_m) for method in METHODS]
    lines += [racing_line(t, margin, "mincurv", car, step_m, blend=w) for w in LIMIT_BLENDS]
    return min(lines, key=lambda line: (line.lap_time, line.flying_lap_time))


def _with_profile(t: Track, sol, method: str, margin: float, car: CarParams, clearance: float) -> RacingLine:
    xy = sol.xy
    k = G.menger_curvature(xy)
    ds = np.hypot(*(np.roll(xy, -1, axis=0) - xy).T)
    flying = P.speed_profile(k, ds, car)
    standing = P.speed_profile(k, ds, car, v_start=0.0)
    # the lap is complete when the model point, 0.14 m ahead of the base point, crosses the start line
    finish = standing.time[-1] - _time_over(standing, ds, MODEL_POINT_AHEAD_M)
    name = f"{t.name}_reversed" if t.reversed else t.name
    return RacingLine(name, method, margin, xy, flying.speed, k, flying.time[:-1], P.timer_lap_time(finish),
                      flying.lap_time, standing.speed, car, clearance, sol.iterations, sol.converged)


def _time_over(profile: P.Profile, ds: np.ndarray, last_m: float) -> float:
    """Time the profile takes over its last `last_m` metres (the loop's end)."""
    s_end = np.concatenate([[0.0], np.cumsum(ds[::-1])])
    t_end = profile.time[-1] - profile.time[::-1]
    return float(np.interp(last_m, s_end, t_end)) if last_m > 0 else 0.0


