"""Example reward for an object avoidance or head-to-bot race (`racerlab init --race object_avoidance` or
`--race head_to_bot`).

A box (or a bot car) stands on a lane line, halfway between the centre line and a border, and a box's crash
footprint reaches just past the centre line, so the only way past is the other lane. The reward asks for exactly
that: follow the lane line on the side away from the next object (or from the one just passed, until the car's
tail is clear of it), point along the track, and go fast. Uses the `objects_*` params as the AWS simulator fills
them, so it works unchanged in the AWS console or DeepRacer-for-Cloud.
"""

import math

CLEAR_BEHIND_M = 0.7  # keep away from an object until it is this far behind (a box's footprint reaches 0.25 m back)


def reward_function(params):
    if params["is_offtrack"] or params["is_crashed"] or not params["all_wheels_on_track"]:
        return 1e-3

    width = params["track_width"]
    offset = params["distance_from_center"] * (1.0 if params["is_left_of_center"] else -1.0)  # + left

    # Where to be across the road: the lane line away from the object that matters, else the centre line.
    target = 0.0
    objects = params["objects_location"]
    if objects:
        previous, following = params["closest_objects"]
        px, py = objects[previous]
        box = previous if math.hypot(px - params["x"], py - params["y"]) < CLEAR_BEHIND_M else following
        box_left = params["objects_left_of_center"][box]
        target = (-0.25 if box_left else 0.25) * width
    lane = max(0.0, 1.0 - (abs(offset - target) / (0.35 * width)) ** 2)

    # Heading: the car against the track's direction between its two closest waypoints (a lane change needs
    # some angle, so the tolerance is wider than for a time trial).
    waypoints = params["waypoints"]
    prev_wp, next_wp = params["closest_waypoints"]
    (x0, y0), (x1, y1) = waypoints[prev_wp], waypoints[next_wp]
    track_heading = math.degrees(math.atan2(y1 - y0, x1 - x0))
    error = abs((params["heading"] - track_heading + 180.0) % 360.0 - 180.0)
    heading = max(0.0, 1.0 - error / 60.0)

    # Speed: rewards are summed per step, so growing with the square of the speed makes faster laps pay more.
    speed = params["speed"] / 4.0
    return float(1e-3 + lane * heading * (0.25 + 4.0 * speed * speed))
