"""Reward template "centre_line": follow the centre line, wheels on the track.

An ordinary AWS DeepRacer reward function (it runs unchanged in the AWS console and DeepRacer for
Cloud). Good for a first model: it teaches staying on the road; it does not ask for speed, so the
laps are as fast as the action space's speeds allow and no faster.
"""


def reward_function(params):
    if params["is_offtrack"] or not params["all_wheels_on_track"]:
        return 1e-3
    # 1 on the centre line, falling smoothly to 0 at the border
    offset = params["distance_from_center"] / (0.5 * params["track_width"])
    return float(max(1e-3, 1.0 - offset * offset))
