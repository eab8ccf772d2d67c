"""The learning core: action distributions, the AWS network topologies, clipped PPO and SAC.

It knows nothing about tracks or files: observations come in as numpy arrays (batch axis first), actions
go out as numpy arrays, and `state_dict()` / `load_state_dict()` are plain dicts for `racerlab.train`
to save.

    >>> from racerlab.agent import PPO, make_batch
    >>> ppo = PPO({"features": (12,)}, metadata, hyperparameters, device="auto", seed=0)
    >>> actions, log_probs, values = ppo.act(obs)            # obs: (B, 12) float32
    >>> ...                                                   # collect [T, B] or flat whole episodes
    >>> metrics = ppo.update(make_batch(obs, actions, log_probs, values, rewards, next_values,
    ...                                 terminated, truncated, gamma=hyperparameters.discount_factor))

What the training loop and evaluation use, the same for PPO and SAC (`make_agent` picks one):
`explore(obs) -> (actions, record)` for a training step (`record`: what `learn` needs kept per step),
`learn(rollout) -> metrics` once per iteration (PPO's update; SAC's replay memory and gradient steps),
and `policy(obs) -> actions`, the greedy actions evaluation drives. A trained checkpoint's weights become a policy
for any reader through `inference_policy` (its greedy actions and its bare networks in eval mode).
"""

from racerlab.agent.build import InferencePolicy, inference_policy, make_agent
from racerlab.agent.common import resolve_device
from racerlab.agent.distributions import (
    Categorical,
    DiagGaussian,
    TanhGaussian,
    epsilon_greedy,
    epsilon_schedule,
)
from racerlab.agent.networks import (
    build_networks,
    build_ppo_networks,
    build_sac_networks,
    count_parameters,
    inference_networks,
    observation_shapes,
    parameter_summary,
)
from racerlab.agent.ppo import (
    PPO,
    PPOBatch,
    compute_gae,
    episode_next_values,
    make_batch,
    minibatch_size,
    ppo_losses,
)
from racerlab.agent.sac import SAC, ReplayBuffer

__all__ = [
    "PPO", "PPOBatch", "SAC", "Categorical", "DiagGaussian", "InferencePolicy", "ReplayBuffer", "TanhGaussian",
    "build_networks", "build_ppo_networks", "build_sac_networks", "compute_gae", "count_parameters",
    "episode_next_values", "epsilon_greedy", "epsilon_schedule", "inference_networks", "inference_policy",
    "make_agent", "make_batch", "minibatch_size", "observation_shapes", "parameter_summary", "ppo_losses",
    "resolve_device",
]
