"""Reward template "pace": how fast the car gains ground along the track, on any track.

An ordinary AWS DeepRacer reward function that follows no line. The track's progress grows at
v * cos(heading error) / (1 - curvature * n): the car's speed along the centre line's direction, gaining
more on the inside of a bend (curvature is the centre line's, signed, + for a left bend; n the car's signed
distance from it, + to its left). Summed over an episode this is the ground covered, so every step of a
quick lap pays more than every step of a slow one and a lap pays for its time, not for a path; going off
track ends the episode and its pay. Paid in units of the top speed (1.0 = 4 m/s straight along the track).
"""

import math

TOP_SPEED = 4.0  # m/s: the reward is 1.0 at this speed along a straight
INSIDE_FLOOR = 0.25  # 1 - curvature * n never counts as less than this (a car far inside a tight bend)


def _curvature(a, b, c):
    """Signed curvature (+ for a left turn) of the circle through three points."""
    abx, aby, bcx, bcy = b[0] - a[0], b[1] - a[1], c[0] - b[0], c[1] - b[1]
    cross = abx * bcy - aby * bcx
    lengths = math.hypot(abx, aby) * math.hypot(bcx, bcy) * math.hypot(c[0] - a[0], c[1] - a[1])
    return 0.0 if lengths == 0 else 2.0 * cross / lengths


def reward_function(params):
    if params["is_offtrack"]:
        return 1e-3
    waypoints = params["waypoints"]
    prev, nxt = params["closest_waypoints"]
    a, b = waypoints[prev], waypoints[nxt]
    after = (nxt + 1) % len(waypoints)
    if tuple(waypoints[after]) == tuple(b):  # a loop's last waypoint repeats its first
        after = (after + 1) % len(waypoints)
    c = waypoints[after]
    heading_error = math.radians(params["heading"]) - math.atan2(b[1] - a[1], b[0] - a[0])
    n = params["distance_from_center"] * (1.0 if params["is_left_of_center"] else -1.0)
    inside = max(1.0 - _curvature(a, b, c) * n, INSIDE_FLOOR)
    rate = params["speed"] * math.cos(heading_error) / inside
    return float(max(rate / TOP_SPEED, 1e-3))
