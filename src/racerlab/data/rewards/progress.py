"""Reward template "progress": progress per step, so a lap in fewer steps earns more.

An ordinary AWS DeepRacer reward function. `progress` is the share of the lap done (0-100) and
`steps` the steps taken (15 per second), so progress / steps is the average pace of the episode so
far: every step of a quick episode is worth more than every step of a slow one, and an episode
earns about its pace times its length. A completed lap gets a bonus that grows as the lap gets
shorter, which makes finishing worth more than any crash-prone sprint.
"""

# A lap of this many steps or more earns no bonus; faster laps earn up to 100.
SLOW_LAP_STEPS = 450  # 30 s at 15 steps per second


def reward_function(params):
    if params["is_offtrack"]:
        return 1e-3
    steps = max(params["steps"], 1.0)
    reward = params["progress"] / steps
    if params["progress"] >= 100.0:
        reward += 100.0 * max(0.0, 1.0 - steps / SLOW_LAP_STEPS)
    return float(max(reward, 1e-3))
