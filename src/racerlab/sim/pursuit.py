"""A batched pure-pursuit driver: follows a path (by default the centre line) at a given speed.

Used to drive laps without learning: the quickstart demo, tests of the episode rules and the
racing-line check that a predicted lap time can be driven.
"""

from __future__ import annotations

import math

import numpy as np

from racerlab.sim import _kernels as K
from racerlab.spec import STEP_S, WHEELBASE_M, CarParams
from racerlab.track import kernels as TK


class PurePursuit:
    """Steer each car toward the point `lookahead_m` ahead on a closed or open path.

    `path` is (M, 2) in driving order; `speed` is a scalar or (M,) per path point (m/s). The
    lookahead grows with speed (`lookahead_m + lookahead_gain_s * v`) so fast sections stay calm.

    Without `car` the commanded speed is the speed of the path point the car is at. With `car`
    (its `CarParams`), `speed` is the speed the car should *have* at each point, and the command
    leads it: it is chosen so that, through the car's first-order speed lag, the car reaches the
    speed of the point it will be at one step later (a speed look-ahead: it brakes in time for a
    corner instead of a lag late, and asks for full throttle while the target is out of reach).
    """

    def __init__(self, path, speed=1.0, closed: bool = True, lookahead_m: float = 0.35,
                 lookahead_gain_s: float = 0.12, wheelbase_m: float = WHEELBASE_M, car: CarParams | None = None):
        p = np.asarray(path, dtype=np.float64)
        if closed and not np.array_equal(p[0], p[-1]):
            p = np.vstack([p, p[:1]])
        self.path = np.ascontiguousarray(p)
        self.closed = closed
        self.seg_len = np.hypot(*np.diff(p, axis=0).T)
        self.cum_s = np.concatenate([[0.0], np.cumsum(self.seg_len)])
        self.length = float(self.cum_s[-1])
        sp = np.broadcast_to(np.asarray(speed, dtype=np.float64), (len(path),)).astype(np.float64)
        self.speed = np.concatenate([sp, sp[:1]]) if len(sp) == len(p) - 1 else sp
        self.lookahead_m = lookahead_m
        self.gain = lookahead_gain_s
        self.wheelbase = wheelbase_m
        self.car = car
        self._hint = None

    @classmethod
    def on_centre_line(cls, track, speed=1.0, **kw) -> PurePursuit:
        return cls(track.center, speed, closed=track.closed, **kw)

    def __call__(self, sim) -> tuple[np.ndarray, np.ndarray]:
        """(steering °, speed m/s) for every car of `sim` from its current pose."""
        n = sim.num_cars
        x, y, yaw, v, w = (sim.car[:, c] for c in (K.CX, K.CY, K.CYAW, K.CV, K.CYAWRATE))
        cp = sim.car_params
        # steer from where the car will be when the command takes hold (its delay and lags: the pose the current
        # speed and yaw rate lead to), through its weak yaw gain (tan δ scaled by the gain at this speed)
        latency = cp.delay_steps * STEP_S + cp.steer_tau_s + cp.yaw_tau_s
        turn = w * latency
        head = yaw + 0.5 * turn
        x = x + v * latency * np.cos(head)
        y = y + v * latency * np.sin(head)
        yaw = yaw + turn
        rear = np.stack([x - 0.5 * self.wheelbase * np.cos(yaw), y - 0.5 * self.wheelbase * np.sin(yaw)], axis=1)
        if self._hint is None or len(self._hint) != n:
            self._hint = np.full(n, -1, np.int64)
        seg = np.empty(n, np.int64)
        t = np.empty(n)
        s = np.empty(n)
        lat = np.empty(n)
        TK.project_many(np.ascontiguousarray(rear), self.path, self.seg_len, self.cum_s, self.closed, self._hint,
                        seg, t, s, lat)
        self._hint = seg
        ld = self.lookahead_m + self.gain * np.maximum(v, 0.0)
        target_s = s + ld
        target_s = np.mod(target_s, self.length) if self.closed else np.minimum(target_s, self.length)
        tx = np.interp(target_s, self.cum_s, self.path[:, 0])
        ty = np.interp(target_s, self.cum_s, self.path[:, 1])
        alpha = np.arctan2(ty - rear[:, 1], tx - rear[:, 0]) - yaw
        dist = np.maximum(np.hypot(tx - rear[:, 0], ty - rear[:, 1]), 1e-6)
        kappa = cp.unsaturated(2.0 * np.sin(alpha) / dist, v)  # the arc; more where the tyres saturate
        steer = np.degrees(np.arctan(self.wheelbase * kappa / cp.yaw_gain_at(v))) - cp.steer_offset_deg
        if self.car is None:
            return steer, np.interp(self._wrap(s), self.cum_s, self.speed)
        return steer, self._speed_command(s + 0.5 * self.wheelbase, v)

    def _wrap(self, s):
        return np.mod(s, self.length) if self.closed else np.clip(s, 0.0, self.length)

    def _speed_command(self, s_base, v):
        """The command that brings speed v to the target through the lag exp(-t/τ), at the point the car will be at
        when the command has acted: one step after its delay."""
        ahead = (1.0 + self.car.delay_steps) * STEP_S
        target = np.interp(self._wrap(s_base + np.maximum(v, 0.0) * ahead), self.cum_s, self.speed)
        tau = self.car.speed_tau_s
        if tau <= 0:
            return target
        keep = math.exp(-STEP_S / tau)  # the share of the old speed left after one step
        return (target - keep * v) / (1.0 - keep)


def drive_lap(sim, controller, max_steps: int = 20_000, car: int = 0):
    """Drive car `car` of `sim` from its current episode start until the episode ends.

    Returns (status name, steps, lap time s, trajectory (T, 2) of base positions). Lap time is
    steps × 1/15 s, the prepare step included, as AWS times a lap (NaN when no lap was completed).
    """
    traj = [sim.car[car, [K.CX, K.CY]].copy()]
    for _ in range(max_steps):
        steer, speed = controller(sim)
        codes = sim.step(steer, speed)
        traj.append(sim.car[car, [K.CX, K.CY]].copy())
        if sim.terminated_mask(codes)[car] or sim.truncated[car]:
            break
    status = K.STATUS_NAMES[int(sim.status[car])]
    steps = int(sim.steps[car])
    # the prepare step is the first of `steps`; AWS's lap time covers every step after reset
    lap_time = steps * sim.dt if status == "lap_complete" else math.nan
    return status, steps, lap_time, np.array(traj)
