"""The car's dynamics: racerlab's model of how the AWS car moves, and how its default limits were chosen.

Geometry (facts §3): wheelbase 0.164 m, wheel track 0.16 m, both front wheels steered by the
same angle clipped to ±30°, commanded speed clipped to [0.1, 4.0] m/s. The pose (x, y, yaw) is
the `base_link` origin, midway between the axles; AWS reports positions for the point 0.14 m
ahead of it (`model_point`).

Dynamics. Gazebo's velocity and position controllers make the v5+ car respond almost at once,
but the physical tyres still limit how hard it can turn. racerlab models both explicitly:

* speed follows the commanded speed with a first-order lag (time constant `speed_tau_s`),
  bounded by an acceleration limit `accel_mps2` and a braking limit `brake_mps2`;
* the steering angle follows the command with a first-order lag `steer_tau_s`;
* the base point moves as a kinematic bicycle (slip angle β with sin β = κ·wheelbase/2 for path
  curvature κ = cos β · tan δ / wheelbase), except that the lateral acceleration v²·κ cannot
  exceed the grip limit `grip_mps2`: beyond it the path curvature is capped at grip / v², so a
  car that enters a corner too fast runs wide (understeers) and leaves the track.

Calibration of the defaults. Gazebo gives the AWS car's wheels a friction coefficient μ = 0.5
(`racecar.gazebo`, facts §3), so tyre forces top out near μ·g = 4.9 m/s²: that is `grip_mps2`
and `brake_mps2`. No source gives the car's acceleration; `accel_mps2` = 3.0 m/s² (a standstill
to 4 m/s in about 1.5 s) is the value that, with the others, puts the theoretical best lap of
`reInvent2019_track` (racing line + speed profile of `racerlab.line`, 4 m/s cap, standing start
timed as the simulator times it) at 6.87 s with the default 0.1 m margin and 6.53 s with none:
inside the 6.5-7.2 s anchor and just under the all-time best human-trained lap in the AWS
simulator there, 7.198 s (reference/track_records.md). The first defaults (grip 6.5, accel 6,
brake 8 m/s²) gave 6.13 s, 15 % under the best lap anyone has driven there. `speed_tau_s`
0.1 s barely matters (0.15 s adds a few hundredths of a second). `benchmarks/racing_line.py` re-measures the
anchor; pure pursuit on the line drives it within a step or two of the prediction.

Each step of 1/15 s is integrated in `substeps` sub-steps. The geometry constants and the `CarParams`
dataclass with these defaults live in `racerlab.spec`; this module holds the compiled dynamics.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from racerlab.spec import CarParams


def pack(car: CarParams) -> np.ndarray:
    """The car's limits packed for the compiled step (`advance` reads them by position)."""
    return np.array([car.wheelbase_m, math.radians(car.max_steer_deg), car.min_speed_mps, car.max_speed_mps,
                     car.speed_tau_s, car.accel_mps2, car.brake_mps2, car.steer_tau_s, car.grip_mps2,
                     float(car.substeps)], dtype=np.float64)


@njit(cache=True)
def advance(x, y, yaw, v, steer, steer_cmd_rad, speed_cmd, hold, car, dt):
    """Integrate one car over `dt`; returns the new (x, y, yaw, v, steer, slip β).

    `car` is `pack(CarParams)`. `hold` keeps the car still (prepare and pause steps).
    """
    if hold:
        return x, y, yaw, 0.0, steer, 0.0
    wb = car[0]
    max_steer = car[1]
    vc = min(max(speed_cmd, car[2]), car[3])
    dc = min(max(steer_cmd_rad, -max_steer), max_steer)
    n = int(car[9])
    h = dt / n
    a_speed = 1.0 - math.exp(-h / car[4]) if car[4] > 0 else 1.0
    a_steer = 1.0 - math.exp(-h / car[7]) if car[7] > 0 else 1.0
    beta = 0.0
    for _ in range(n):
        dv = (vc - v) * a_speed
        dv = min(max(dv, -car[6] * h), car[5] * h)
        v_mid = v + 0.5 * dv
        v = v + dv
        steer = steer + (dc - steer) * a_steer
        tan_d = math.tan(steer)
        cos_b = 1.0 / math.sqrt(1.0 + 0.25 * tan_d * tan_d)
        kappa = cos_b * tan_d / wb
        if v_mid > 1e-6:
            k_max = car[8] / (v_mid * v_mid)
            kappa = min(max(kappa, -k_max), k_max)
        sb = min(max(0.5 * kappa * wb, -1.0), 1.0)
        beta = math.asin(sb)
        dyaw = v_mid * kappa * h
        head = yaw + 0.5 * dyaw + beta
        x += v_mid * h * math.cos(head)
        y += v_mid * h * math.sin(head)
        yaw += dyaw
    if yaw > math.pi:
        yaw -= 2.0 * math.pi
    elif yaw <= -math.pi:
        yaw += 2.0 * math.pi
    return x, y, yaw, v, steer, beta
