"""The car's dynamics: racerlab's model of how the AWS simulator's car moves, fitted to its logs.

Geometry (facts §3): wheelbase 0.164 m, wheel track 0.16 m, both front wheels steered by the same angle
clipped to ±30°, commanded speed clipped to [0.1, 4.0] m/s. The pose (x, y, yaw) is the `base_link`
origin, midway between the axles; AWS reports positions for the point 0.14 m ahead of it (`model_point`).

What the real simulator does (docs/car.md has the measurements) and how racerlab models it, per step:

* **delay**: a row's action starts to act `delay_steps` steps later (a fraction means part-way through
  the step: for that part the car still follows the action before). The compiled step keeps the last
  commands of every car for this.
* **hinge lag**: the steering angle follows the (delayed) command with a first-order lag `steer_tau_s`
  (ROS 2: the position controller closes 10 % of the error per 1/60 s tick, τ ≈ 0.167 s); with `steer_kick` a
  change of the command moves the wheels that share of it at once (ROS 1's hinge PID answers through its derivative
  term: the cars turned too little under fast-changing commands).
* **yaw gain and slide**: the car turns like a kinematic bicycle whose tan δ is scaled by
  `yaw_gain / (1 + (v / slide_mps)²)` (no Ackermann, no differential, tyre slip: 0.55-0.63 at low speed;
  on ROS 1 it falls to 0.25-0.3 above 1.5 m/s); with `tyre_sat_mps2` the tyres saturate: the curvature κ the
  wheels ask for becomes κ / √(1 + (v²κ / tyre_sat_mps2)²), so that the lateral acceleration approaches it (the ROS 1
  console car turns less the harder it corners); the lateral acceleration is also capped at `grip_mps2`.
* **front drive**: with `front_drive` (the ROS 1 velocity car, whose velocity controllers drive the steered front
  wheels too) a change of the ground speed at a m/s² bends the path by front_drive · a · sin δ / max(v², 1 m²/s²)
  more: the front wheels' share of the drive pushes along their angle, so the car turns more while it speeds up and
  less while it brakes; at a held speed it adds nothing.
* **wheel offset**: the wheels point `steer_offset_deg` left of the hinges' (commanded) angle: the 2022 effort-car
  logs (ROS 1, effort hinges) turn left of the model's car whatever the command (0 = none).
* **speed**: the ground speed follows a target with a first-order lag `speed_tau_s`, bounded by the
  traction limits `accel_mps2` and `brake_mps2`; with `accel_fade_mps` (the ROS 1 velocity car) the acceleration
  falls with speed as 1 - (v / fade)² and turns into a slowdown above the fade speed, the car's top speed. The
  target is the command clipped to the wheel joints' velocity cap `wheel_cap_mps` (100 rad/s x 0.035 m) times
  `ground_factor` (the wheel mesh's 0.036 m radius against the controller's 0.035 m: 1.03). Effort-controlled
  cars without a speed loop (`regulated` False: version 3-4 models on the ROS 2 simulator) always drive toward
  the cap.
* **step length**: a real step lasts 0.05-0.08 s of simulated time rather than 1/15 s; with `step_jitter`
  the simulator draws each car's step from the measured distribution (`spec.STEP_LENGTHS`, mean 1/15 s).
  A log's tstamps give its steps' lengths by that simulator's rule (`LOG_TIMING`, `step_durations`).

`rollout` replays logged actions from a logged state with this model (the calibration, `racerlab
calibrate`, fits the constants with it); `advance` is the compiled integration the simulator steps every
car with. The constants of each simulator and model version are in `racerlab.spec` (`CAR_TABLE`,
`car_params`); what each constant is, and whether it is packed, drawn and fitted, is its row of
`spec.CAR_CONSTANTS`, from which `pack`'s order (the `P_*` positions the kernels read) and `RANDOMISED` come.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from racerlab.sim.rollout_inputs import check_rollout_inputs
from racerlab.spec import (
    CAR_CONSTANTS,
    CAR_SPREAD,
    MAX_DELAY_STEPS,
    MODEL_POINT_AHEAD_M,
    STEP_LENGTHS,
    STEP_QUANTILES,
    STEP_S,
    CarConstant,
    CarParams,
    car_params,
    constants_by_name,
)

QUEUE = int(MAX_DELAY_STEPS) + 2  # commands kept per car: this step's and the ones before it
_FORMS = {"value": float, "radians": math.radians}  # how a packed constant is stored (`CarConstant.packed`)


@functools.cache
def packed_rows(table: tuple[CarConstant, ...] = CAR_CONSTANTS) -> tuple[CarConstant, ...]:
    """The rows of `table` the compiled step reads, in the order of `pack`'s array."""
    return tuple(c for c in table if c.packed)


@functools.cache
def columns(table: tuple[CarConstant, ...] = CAR_CONSTANTS) -> dict[str, int]:
    """Each packed constant's position in `pack`'s array: its place among `table`'s packed rows."""
    return {c.name: i for i, c in enumerate(packed_rows(table))}


def pack(car: CarParams) -> np.ndarray:
    """The car's constants packed for the compiled step (`advance` reads them by position, `columns`)."""
    return np.array([_FORMS[c.packed](getattr(car, c.name)) for c in packed_rows(car.TABLE)], dtype=np.float64)


# positions in `pack`'s array, module constants so that numba compiles them into the kernels
_COL = columns()
P_WB, P_MAX_STEER, P_MIN_SPEED, P_MAX_SPEED = (_COL[n] for n in ("wheelbase_m", "max_steer_deg", "min_speed_mps",
                                                                 "max_speed_mps"))
P_DELAY, P_STEER_TAU, P_YAW_GAIN, P_SLIDE, P_YAW_TAU, P_SPEED_TAU = (
    _COL[n] for n in ("delay_steps", "steer_tau_s", "yaw_gain", "slide_mps", "yaw_tau_s", "speed_tau_s"))
P_ACCEL, P_BRAKE, P_GROUND, P_FADE, P_KICK, P_SAT, P_DRIVE, P_OFFSET = (
    _COL[n] for n in ("accel_mps2", "brake_mps2", "ground_factor", "accel_fade_mps", "steer_kick", "tyre_sat_mps2",
                      "front_drive", "steer_offset_deg"))
P_CAP, P_REGULATED, P_GRIP, P_SUBSTEPS = (_COL[n] for n in ("wheel_cap_mps", "regulated", "grip_mps2", "substeps"))


# How each simulator's simtraces stamp their steps (docs/car.md, "The logs' step timing"), by (simulator, control):
# "previous": a row's pose belongs to the previous row's tstamp, so the step from row j to j+1 lasts
# t[j] - t[j-1] (console v5, ROS 1 velocity; DRoA, ROS 2); "fixed": the tstamps carry no information about the
# motion (the 2022 effort-car logs), every step lasts 1/15 s; "next" (t[j+1] - t[j]) is the naive reading.
TIMINGS = ("previous", "fixed", "next")
LOG_TIMING = {("droa", "velocity"): "previous", ("droa", "effort"): "previous",
              ("console", "velocity"): "previous", ("console", "effort"): "fixed"}


# Steps the start's mean speed and yaw rate are measured over, by timing rule. Where the steps' lengths are known
# ("previous", "next") the last step alone; where they are not ("fixed": every step read as 1/15 s while the real
# ones jitter about ±0.008 s) the least-squares line through the last three poses, i.e. their difference over two
# steps: one step's unknown length puts about ±12 % of noise into a rate over it, two steps' ±8.5 %.
START_STEPS = {"previous": 1, "fixed": 2, "next": 1}


def log_timing(car: CarParams) -> str:
    """The timing rule of the logs of `car`'s simulator and control (`LOG_TIMING`)."""
    return LOG_TIMING[(car.simulator, car.control)]


def step_durations(tstamps, timing: str) -> np.ndarray:
    """(n - 1,) the lengths (s) of the steps from row j to row j + 1 of n logged `tstamps` by the rule `timing`
    (`TIMINGS`); NaN where the rule needs a row before the first."""
    t = np.asarray(tstamps, dtype=np.float64).ravel()
    n = len(t)
    if timing == "fixed":
        return np.full(max(n - 1, 0), STEP_S)
    if timing == "next":
        return np.diff(t)
    if timing == "previous":
        return np.concatenate([[math.nan], np.diff(t)[:-1]]) if n > 1 else np.empty(0)
    raise ValueError(f"unknown step timing {timing!r}; use one of {', '.join(TIMINGS)}")


@functools.cache
def randomised_rows(table: tuple[CarConstant, ...] = CAR_CONSTANTS) -> dict[str, tuple[int, float]]:
    """Each randomised constant of `table`: its place in `pack`'s array and the least it may be drawn."""
    cols = columns(table)
    return {c.name: (cols[c.name], c.randomised) for c in table if c.randomised is not None}


RANDOMISED = randomised_rows()
SPREAD_CLIP = 2.0  # draws stay within this many spreads of the fitted value


def randomised(car: CarParams, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, P) packed constants of n cars drawn around `car` (randomised dynamics, `[car] randomise`): each constant
    of `spec.CAR_SPREAD` (the fit's spread over resampled episodes) normal around its value with `car.randomise`
    times that spread, cut at SPREAD_CLIP spreads, no lower than its row's `randomised` and no higher than its valid
    range; a constant that is off (slide, fade, saturation, front drive: 0) stays off."""
    out = np.tile(pack(car), (n, 1))
    drawn = randomised_rows(car.TABLE)
    rows = constants_by_name(car.TABLE)
    for name, sd in CAR_SPREAD.get((car.simulator, car.control), {}).items():
        col, low = drawn[name]
        if not car.has(name):
            continue
        z = np.clip(rng.standard_normal(n), -SPREAD_CLIP, SPREAD_CLIP)
        draw = np.minimum(np.maximum(getattr(car, name) + car.randomise * sd * z, low), rows[name].valid.high)
        out[:, col] = np.radians(draw) if rows[name].packed == "radians" else draw
    return out


def step_lengths(rng: np.random.Generator, n: int, simulator: str) -> np.ndarray:
    """`n` step lengths (s) drawn from `simulator`'s measured distribution."""
    return np.interp(rng.random(n), STEP_QUANTILES, STEP_LENGTHS[simulator])


@njit(cache=True, inline="always")
def _saturate(kappa, v, car):
    """The curvature `kappa` the wheels ask for at `v`, with the tyres saturating toward `tyre_sat_mps2` of lateral
    acceleration: κ / √(1 + (v²κ / sat)²) (ROS 1: the console cars turn less the harder they corner; 0 = off)."""
    if car[P_SAT] <= 0:
        return kappa
    a = v * v * kappa / car[P_SAT]
    return kappa / math.sqrt(1.0 + a * a)


@njit(cache=True, inline="always")
def _path_curvature(v, steer, car):
    """The curvature (1/m) the base point follows at `v` with the hinges at `steer` (rad; the wheels point
    `steer_offset_deg` left of it): the bicycle's through the yaw gain (falling with speed where the car slides),
    the tyres' saturation, and at most the grip."""
    gain = car[P_YAW_GAIN]
    if car[P_SLIDE] > 0:
        r = v / car[P_SLIDE]
        gain = gain / (1.0 + r * r)
    tan_d = gain * math.tan(steer + car[P_OFFSET])
    kappa = _saturate(tan_d / (car[P_WB] * math.sqrt(1.0 + 0.25 * tan_d * tan_d)), v, car)
    if v > 1e-6:
        k_max = car[P_GRIP] / (v * v)
        kappa = min(max(kappa, -k_max), k_max)
    return kappa


@njit(cache=True, inline="always")
def _drive_curvature(accel, v, steer, car):
    """The curvature (1/m) the steered front wheels (at `steer` plus their offset) add at `v` while the ground speed
    changes by `accel` m/s²: their share `front_drive` of the drive pushes along their angle, a sideways
    acceleration front_drive · accel · sin δ (ROS 1 drives the front wheels too: the car turns more while it speeds
    up, less while it brakes; 0 = off). Below 1 m/s it counts as at 1 m/s."""
    if car[P_DRIVE] <= 0:
        return 0.0
    return car[P_DRIVE] * accel * math.sin(steer + car[P_OFFSET]) / max(v * v, 1.0)


@njit(cache=True)
def yaw_rate(v, steer, car):
    """The yaw rate (rad/s) the car settles at driving at `v` with the wheels at `steer` (rad)."""
    return v * _path_curvature(v, steer, car)


@njit(cache=True, inline="always")
def _target_speed(speed_cmd, car):
    """The ground speed a command asks for: clipped, capped by the wheels (or the cap itself without a speed
    loop), times the ground factor."""
    vc = min(max(speed_cmd, car[P_MIN_SPEED]), car[P_MAX_SPEED])
    return (min(vc, car[P_CAP]) if car[P_REGULATED] > 0.5 else car[P_CAP]) * car[P_GROUND]


@njit(cache=True, inline="always")
def accel_limit(v, car):
    """The most the ground speed can gain per second at `v`: `accel_mps2`, falling as 1 - (v / accel_fade_mps)² when
    the fade is set (ROS 1: traction and the wheel loop's effort run out), below 0 above the fade speed (the car
    slows even when asked for more), never below -`brake_mps2`."""
    a = car[P_ACCEL]
    if car[P_FADE] > 0:
        r = v / car[P_FADE]
        a = a * (1.0 - r * r)
    return max(a, -car[P_BRAKE])


@njit(cache=True, inline="always")
def _speed_sub(v, vt, a_speed, h, car):
    """One sub-step of the ground speed toward `vt`: (mid-step speed, new speed)."""
    dv = (vt - v) * a_speed
    dv = min(max(dv, -car[P_BRAKE] * h), accel_limit(v, car) * h)
    return v + 0.5 * dv, v + dv


@njit(cache=True)
def _speed_over(v, old_speed, new_speed, car, dt):
    """The ground speed alone over one step (commands as in `advance`): (mean speed, end speed)."""
    n = int(car[P_SUBSTEPS])
    frac = car[P_DELAY] - math.floor(car[P_DELAY])
    n1 = max(1, int(round(n * frac))) if frac > 1e-9 else 0
    dist = 0.0
    for cmd, span, k in ((old_speed, frac * dt, n1), (new_speed, (1.0 - frac) * dt, max(1, n - n1))):
        if k == 0:
            continue
        h = span / k
        a_speed = 1.0 - math.exp(-h / car[P_SPEED_TAU]) if car[P_SPEED_TAU] > 0 else 1.0
        vt = _target_speed(cmd, car)
        for _ in range(k):
            v_mid, v = _speed_sub(v, vt, a_speed, h, car)
            dist += v_mid * h
    return dist / dt, v


@njit(cache=True)
def _phase(x, y, yaw, v, steer, w, steer_cmd, speed_cmd, car, span, n):
    """Integrate `span` seconds in `n` sub-steps toward one command; returns (x, y, yaw, v, steer, ω, β)."""
    wb = car[P_WB]
    dc = min(max(steer_cmd, -car[P_MAX_STEER]), car[P_MAX_STEER])
    vt = _target_speed(speed_cmd, car)
    h = span / n
    a_speed = 1.0 - math.exp(-h / car[P_SPEED_TAU]) if car[P_SPEED_TAU] > 0 else 1.0
    a_steer = 1.0 - math.exp(-h / car[P_STEER_TAU]) if car[P_STEER_TAU] > 0 else 1.0
    a_yaw = 1.0 - math.exp(-h / car[P_YAW_TAU]) if car[P_YAW_TAU] > 0 else 1.0
    beta = 0.0
    for _ in range(n):
        v_old = v
        v_mid, v = _speed_sub(v, vt, a_speed, h, car)
        steer = steer + (dc - steer) * a_steer
        kappa = _path_curvature(v_mid, steer, car) + _drive_curvature((v - v_old) / h, v_mid, steer, car)
        w = w + (v_mid * kappa - w) * a_yaw
        beta = math.asin(min(max(0.5 * kappa * wb, -1.0), 1.0))
        dyaw = w * h
        head = yaw + 0.5 * dyaw + beta
        x += v_mid * h * math.cos(head)
        y += v_mid * h * math.sin(head)
        yaw += dyaw
    return x, y, yaw, v, steer, w, beta


@njit(cache=True, inline="always")
def _kick(steer, old, new, car):
    """The hinge's jump when its (delayed) command changes from `old` to `new`: `steer_kick` of the change at once
    (ROS 1's hinge PID answers a command step through its derivative term before the lag), kept within the lock."""
    if car[P_KICK] <= 0:
        return steer
    ms = car[P_MAX_STEER]
    steer += car[P_KICK] * (min(max(new, -ms), ms) - min(max(old, -ms), ms))
    return min(max(steer, -ms), ms)


@njit(cache=True)
def advance(x, y, yaw, v, steer, w, old_steer, old_speed, new_steer, new_speed, hold, car, dt):
    """Integrate one car over one step of `dt` s; returns the new (x, y, yaw, v, steer, yaw rate ω, slip β).

    Steering commands in radians. The step follows (old_steer, old_speed) for the fraction of the delay
    (`delay_steps` - floor) and (new_steer, new_speed) after it. `car` is `pack(CarParams)`. `hold` keeps
    the car still (prepare and pause steps).
    """
    if hold:
        return x, y, yaw, 0.0, steer, 0.0, 0.0
    n = int(car[P_SUBSTEPS])
    frac = car[P_DELAY] - math.floor(car[P_DELAY])
    beta = 0.0
    if frac > 1e-9:
        n1 = max(1, int(round(n * frac)))
        x, y, yaw, v, steer, w, beta = _phase(x, y, yaw, v, steer, w, old_steer, old_speed, car, frac * dt, n1)
    steer = _kick(steer, old_steer, new_steer, car)
    x, y, yaw, v, steer, w, beta = _phase(x, y, yaw, v, steer, w, new_steer, new_speed, car, (1.0 - frac) * dt,
                                          max(1, n - int(round(n * frac))))
    if yaw > math.pi:
        yaw -= 2.0 * math.pi
    elif yaw <= -math.pi:
        yaw += 2.0 * math.pi
    return x, y, yaw, v, steer, w, beta


@njit(cache=True)
def _settle(steer, old, new, car, dt):
    """The hinge alone over one step (the start's steering angle estimated from the history)."""
    frac = car[P_DELAY] - math.floor(car[P_DELAY])
    tau = car[P_STEER_TAU]
    ms = car[P_MAX_STEER]
    t = min(max(old, -ms), ms)
    steer = t + (steer - t) * (math.exp(-frac * dt / tau) if tau > 0 else 0.0)
    steer = _kick(steer, old, new, car)
    t = min(max(new, -ms), ms)
    return t + (steer - t) * (math.exp(-(1.0 - frac) * dt / tau) if tau > 0 else 0.0)


@njit(cache=True)
def _speed_from_mean(mean, old_speed, new_speed, car, dt):
    """The speed at the end of a step whose mean speed was `mean` (the last position difference): the start speed
    whose step, under the car's own speed model, averages `mean`, found by a few fixed-point rounds."""
    v0 = mean
    end = mean
    for _ in range(6):
        m, end = _speed_over(v0, old_speed, new_speed, car, dt)
        v0 = max(v0 + (mean - m), 0.0)
    return end


@njit(cache=True)
def rollout_batch(start, commands, first, dts, car, mean_speed=False, prev_dt=None):
    """Replay many logged stretches at once: (N, k, 3) front x, y, heading (degrees) after each action.

    start: (N, 6) front x, y, heading (rad), ground speed, wheel angle (rad; NaN: estimated from the history
    by the hinge's lag), yaw rate (rad/s; NaN: the one the wheel angle and speed settle at). commands: (N, m + k, 2)
    steering (rad) and speed, the history's m then the k actions
    to replay; first: m (the index of the first replayed action); dts: (N, k) step lengths. With `mean_speed` the
    start's speed is the mean over the step before (of `prev_dt[i]` s), the car's own model giving the speed now.
    """
    nrun = start.shape[0]
    k = dts.shape[1]
    out = np.empty((nrun, k, 3))
    delay = car[P_DELAY]
    d = int(math.floor(delay))
    for i in range(nrun):
        yaw = start[i, 2]
        x = start[i, 0] - MODEL_POINT_AHEAD_M * math.cos(yaw)
        y = start[i, 1] - MODEL_POINT_AHEAD_M * math.sin(yaw)
        v = start[i, 3]
        if mean_speed and first > 0:
            r = first - 1
            v = _speed_from_mean(v, commands[i, max(r - d - 1, 0), 1], commands[i, max(r - d, 0), 1], car,
                                 prev_dt[i])
        steer = start[i, 4]
        if math.isnan(steer):
            steer = min(max(commands[i, 0, 0], -car[P_MAX_STEER]), car[P_MAX_STEER])
            for r in range(first):
                steer = _settle(steer, commands[i, max(r - d - 1, 0), 0], commands[i, max(r - d, 0), 0], car, STEP_S)
        w = start[i, 5]
        if math.isnan(w):
            w = yaw_rate(v, steer, car)
        for j in range(k):
            r = first + j
            o = commands[i, max(r - d - 1, 0)]
            c = commands[i, max(r - d, 0)]
            x, y, yaw, v, steer, w, _ = advance(x, y, yaw, v, steer, w, o[0], o[1], c[0], c[1], False, car, dts[i, j])
            out[i, j, 0] = x + MODEL_POINT_AHEAD_M * math.cos(yaw)
            out[i, j, 1] = y + MODEL_POINT_AHEAD_M * math.sin(yaw)
            out[i, j, 2] = math.degrees(yaw)
    return out


def rollout(start, actions, *, history=None, version="5", simulator="droa", car: CarParams | None = None,
            dt=None, tstamps=None) -> np.ndarray:
    """Where the car goes when it is given `actions` from `start`: (k, 3) front x, y (m) and heading (°).

    The semantics are a simtrace row's (facts §7): `start` is the state a row logs, a dict with `x`, `y`
    (the front point, m), `heading` (degrees), `speed` (the ground speed now, m/s) or instead `mean_speed` (the
    last position difference over its step of `mean_dt` s, default 1/15 s: the car's own speed model then works out
    the speed now from the history's commands), `steering_angle` (the front wheels' angle, degrees; None estimates
    it from `history`) and, optionally, `yaw_rate` (°/s, e.g. the last heading difference over its step; missing:
    the one the wheel angle and speed settle at);
    `actions` (k, 2) are the [steering_angle °, speed m/s] of that row and the k - 1 rows after it, as
    logged; row j of the result is the pose the next row logs after action j. `history` (m, 2) holds the
    actions of the rows before `start`, oldest first: the car is still acting on those for its delay
    (missing ones repeat the oldest given, or, with no history, stand for the start's wheel angle and
    speed). The car is `simulator`'s for a model of `version` (`spec.car_params`), or `car`. The steps' lengths:
    `dt` (k values, or one for all; default 1/15 s), or `tstamps`, the logged tstamps of the history's rows, the
    start row and the k rows after (m + 1 + k values), read by the car's simulator's rule (`LOG_TIMING`; the start's
    `mean_dt` then comes from them too: the last `START_STEPS[rule]` steps' length, so under the "fixed" rule of the
    2022 effort-car logs `mean_speed` and `yaw_rate` are the position and heading differences over the last two steps,
    as `racerlab calibrate` measures them).
    """
    car = car or car_params(simulator, version)
    check_rollout_inputs(start, actions, history, dt, car)
    acts = np.asarray(actions, dtype=np.float64).reshape(-1, 2)
    steer0 = start.get("steering_angle")
    if history is None or len(history) == 0:
        v0 = float(start["speed"] if "speed" in start else start["mean_speed"])
        hist = np.array([[0.0 if steer0 is None else float(steer0), v0 / car.ground_factor]])
        m = 0
    else:
        hist = np.asarray(history, dtype=np.float64).reshape(-1, 2)
        m = len(hist)
    cmds = np.concatenate([hist, acts])
    cmds[:, 0] = np.radians(cmds[:, 0])
    k = len(acts)
    dts, mean_dt = _step_times(k, m, dt, tstamps, car, start.get("mean_dt", STEP_S))
    w0 = start.get("yaw_rate")
    mean = "mean_speed" in start and "speed" not in start
    st = np.array([[start["x"], start["y"], math.radians(start["heading"]), start["mean_speed" if mean else "speed"],
                    math.nan if steer0 is None else math.radians(steer0),
                    math.nan if w0 is None else math.radians(w0)]], dtype=np.float64)
    return rollout_batch(st, cmds[None], len(hist), dts[None], pack(car), mean, np.array([mean_dt]))[0]


def _step_times(k: int, m: int, dt, tstamps, car: CarParams, mean_dt) -> tuple[np.ndarray, float]:
    """`rollout`'s k step lengths and the start's `mean_dt`, from `dt` or the logged `tstamps`."""
    if tstamps is None:
        dts = np.full(k, STEP_S) if dt is None else np.broadcast_to(np.asarray(dt, dtype=np.float64).ravel(), (k,))
        return np.ascontiguousarray(dts, dtype=np.float64), float(mean_dt)
    if dt is not None:
        raise ValueError("rollout takes dt or tstamps, not both")
    t = np.asarray(tstamps, dtype=np.float64).ravel()
    if len(t) != m + 1 + k:
        raise ValueError(f"rollout's tstamps need m + 1 + k = {m + 1 + k} values (the history's rows, the start row "
                         f"and the {k} rows after), got {len(t)}")
    rule = log_timing(car)
    d = step_durations(t, rule)  # d[j]: row j -> j + 1; the start row is row m
    d = np.where(np.isfinite(d), d, STEP_S)
    n = min(START_STEPS[rule], m)  # the steps the start's mean speed is measured over
    return np.ascontiguousarray(d[m:m + k]), float(d[m - n:m].sum()) if n > 0 else float(mean_dt)
