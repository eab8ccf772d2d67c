"""The racer's reward function, in one place: loading `reward_function.py` (`reward.load`), calling it with the
one validity rule (`reward.call`), the time budget of a call (`reward.watchdog`) and the files racerlab writes
(`reward.templates`). Building the params a call gets is the simulator's (`sim.params`) or, from logs,
`analysis.rescore`'s.
"""

from racerlab.reward.call import (
    MAX_ABS_REWARD,
    RewardCaller,
    as_reward_caller,
    as_reward_function,
    check_value,
    describe_exception,
    describe_params,
    return_location,
    source_of,
)
from racerlab.reward.load import error_location, load_reward_function
from racerlab.reward.templates import EXAMPLE_REWARD, EXAMPLE_REWARDS, TEMPLATES, reward_source
from racerlab.reward.watchdog import RewardTimeout, RewardWatchdog

__all__ = [
    "EXAMPLE_REWARD", "EXAMPLE_REWARDS", "MAX_ABS_REWARD", "TEMPLATES", "RewardCaller", "RewardTimeout",
    "RewardWatchdog", "as_reward_caller", "as_reward_function", "check_value", "describe_exception", "describe_params",
    "error_location", "load_reward_function", "return_location", "reward_source", "source_of",
]
