"""Reward template "racing_line": drive on a racing line at the speed the car can hold there.

An ordinary AWS DeepRacer reward function, self-contained. `racerlab init --reward racing_line`
fills RACING_LINE with the line `racerlab line` computes for the model's track (minimum curvature,
the car's grip and acceleration limits), its speeds capped at the action space's top speed; it
runs unchanged in the AWS console on the same track.

Each step earns closeness to the line (1 on it, 0 at half a track width away) times how well the
commanded speed matches the line's speed there (1 when equal, 0 when off by the full target),
plus a little for progress so that an early, clumsy policy is still pulled around the lap.
"""

import math

TRACK = "__TRACK__"
RACING_LINE = []  # [[x, y, speed], ...] in driving order, about every 0.2 m (filled in by racerlab init)


def _closest(x, y):
    best, best_d2 = 0, float("inf")
    for i, (px, py, _) in enumerate(RACING_LINE):
        d2 = (px - x) ** 2 + (py - y) ** 2
        if d2 < best_d2:
            best, best_d2 = i, d2
    return best, math.sqrt(best_d2)


def reward_function(params):
    if params["is_offtrack"]:
        return 1e-3
    i, distance = _closest(params["x"], params["y"])
    target = RACING_LINE[i][2]
    near = max(0.0, 1.0 - distance / (0.5 * params["track_width"]))
    pace = max(0.0, 1.0 - abs(params["speed"] - target) / target)
    pull = 0.1 * params["progress"] / 100.0
    return float(1e-3 + near * pace + pull)
