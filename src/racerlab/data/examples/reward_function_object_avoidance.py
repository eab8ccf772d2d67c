"""Example reward for an object avoidance or head-to-bot race (`racerlab init --race object_avoidance` or
`--race head_to_bot`).

Stay on the track, keep near the centre while the road ahead is clear, and when the next box (or bot car) is
close and in your lane, be in the other lane. Uses the `objects_*` params as the AWS simulator fills them.
"""

import math


def reward_function(params):
    if params["is_offtrack"] or params["is_crashed"] or not params["all_wheels_on_track"]:
        return 1e-3

    reward = 1.0
    track_width = params["track_width"]
    # keep the car reasonably centred: full reward in the middle half of the road
    if params["distance_from_center"] > 0.25 * track_width:
        reward *= 0.5

    objects = params["objects_location"]
    if objects:
        _, next_object = params["closest_objects"]
        ox, oy = objects[next_object]
        gap = math.hypot(ox - params["x"], oy - params["y"])
        same_side = params["objects_left_of_center"][next_object] == params["is_left_of_center"]
        if gap < 1.5:
            # a box in our lane: the closer, the smaller the reward (change lanes early); beside us: a bonus
            reward *= min(max(gap - 0.5, 0.0), 1.0) + 1e-3 if same_side else 1.5
    return float(reward)
