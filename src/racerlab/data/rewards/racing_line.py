"""Reward template "racing_line": drive on a racing line at the speed the car can hold there.

An ordinary AWS DeepRacer reward function, self-contained. `racerlab init --reward racing_line`
fills RACING_LINE with the kind of path of the track's theoretical limit (`racerlab line`: the
fastest of minimum curvature, shortest path and their mixes, at the car's grip and acceleration
limits) kept a margin from the borders (`--line-margin`, default -0.1 m: the wheels 0.1 m over the
border, 0.13 m short of the off-track rule), its speeds capped at the action space's top speed; it
runs unchanged in the AWS console on the same track.

Each step earns closeness to the line (1 on it, 0 at half a track width away) times the pace: the
square of commanded speed / the line's speed there, up to the line's speed, falling to 0 at 1.5 times
it. Squared, so that a lap driven faster earns more in total: a step at a fraction f of the line's
speed covers f times the distance, so a lap takes 1/f times the steps, and the lap earns about f
times what it earns at the line's speeds. (Linear in f, a slow lap would earn as much as a fast one:
fewer but richer steps against more but poorer ones; a term growing with `progress` would even pay
for slowness, since a slow car spends more steps at every progress.)
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
    ratio = params["speed"] / target
    pace = ratio * ratio if ratio <= 1.0 else max(0.0, 1.0 - 2.0 * (ratio - 1.0))
    return float(1e-3 + near * pace)
