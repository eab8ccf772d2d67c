"""racerlab's example reward function: stay near the centre line, keep the wheels on, go fast.

It is an ordinary AWS DeepRacer reward function: `params` holds exactly the keys the AWS
simulator passes (x, y, heading, progress, speed, track_width, distance_from_center, waypoints,
closest_waypoints, ...), so this file works unchanged in the AWS console or DeepRacer-for-Cloud.
"""

import math


def reward_function(params):
    # Off the road (no wheel on it), or some wheels off: almost nothing. Never return 0 or a
    # negative number by habit: AWS accepts any finite value within ±1e5, but a small positive
    # floor keeps the returns of bad episodes comparable.
    if params["is_offtrack"]:
        return 1e-3
    if not params["all_wheels_on_track"]:
        return 1e-3

    # Centre: 1 on the centre line, falling smoothly to 0 at the border.
    half_width = 0.5 * params["track_width"]
    centre = max(0.0, 1.0 - (params["distance_from_center"] / half_width) ** 2)

    # Heading: compare the car with the direction of the track between its two closest waypoints.
    waypoints = params["waypoints"]
    prev_wp, next_wp = params["closest_waypoints"]
    (x0, y0), (x1, y1) = waypoints[prev_wp], waypoints[next_wp]
    track_heading = math.degrees(math.atan2(y1 - y0, x1 - x0))
    error = abs((params["heading"] - track_heading + 180.0) % 360.0 - 180.0)
    heading = max(0.0, 1.0 - error / 45.0)

    # Speed: rewards are summed per step and a slow lap has more steps, so a reward that grows only in
    # proportion to speed would not prefer fast laps. Growing with the square of the commanded speed
    # (m/s) makes a faster lap earn more in total.
    speed = params["speed"] / 4.0

    return float(1e-3 + centre * heading * (0.25 + 4.0 * speed * speed))
