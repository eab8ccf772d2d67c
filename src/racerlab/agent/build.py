"""An agent for a model: `make_agent` (PPO or SAC, per its model_metadata.json) and `inference_policy`, the one way
from a trained checkpoint's weights to a policy for every reader.

Evaluation and races drive its greedy actions, the camera model's teacher labels with them, and the exports
convert its bare networks (the car's model.pb, ONNX, TFLite, DRoA/DRfC's TF checkpoint). It is built through the
agent itself (`make_agent` + `load_state_dict`), so its actions are exactly the greedy ones training's evaluation
drives (the argmax or the mean; a vector network's NumPy path), and weights that do not fit the network built for
the inputs are refused with one wording (`errors.ModelRefused`, reason `NETWORK`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from torch import nn

from racerlab.agent.networks import inference_networks, observation_shapes
from racerlab.agent.ppo import PPO
from racerlab.agent.sac import SAC
from racerlab.errors import ModelRefused
from racerlab.model import Hyperparameters, ModelMetadata
from racerlab.model.checkpoint import WEIGHTS_ONLY_KEY


@dataclass(frozen=True, eq=False)
class InferencePolicy:
    """A checkpoint's trained networks, in eval mode. Called with a batch of observations (or through `policy`, the
    agent's own name for it, so that it stands in wherever an agent's greedy actions are asked for) it gives the
    greedy actions: [B] action indices (discrete: the argmax) or [B, 2] (continuous: the mean, SAC's tanh of it)."""

    metadata: ModelMetadata
    shapes: dict[str, tuple[int, ...]]  # the inputs: name -> one observation's shape
    networks: dict[str, nn.Module]  # `inference_networks(metadata)` -> module: policy, value (PPO) or actor (SAC)
    policy: Callable[..., np.ndarray] = field(repr=False)  # the agent's `policy(obs)`

    def __call__(self, obs) -> np.ndarray:
        return self.policy(obs)


def inference_policy(obs, metadata: ModelMetadata, weights: dict, *, where,
                     hyperparameters: Hyperparameters | None = None, device: str = "cpu") -> InferencePolicy:
    """The policy of `weights` (an agent's `state_dict()`, as a checkpoint's `state.agent` holds it) for inputs
    `obs` (a gymnasium space or name -> shape, as `make_agent` takes them). `where` (the checkpoint's path) names
    it in the `ModelRefused` line when the weights do not fit the network `metadata` gives for these inputs."""
    agent = make_agent(obs, metadata, hyperparameters, device=device, seed=0)  # greedy: the seed draws nothing
    shapes = observation_shapes(obs, metadata)
    if WEIGHTS_ONLY_KEY in weights:  # a race server's stored model: its networks alone; the optimiser and counters,
        # which greedy actions never read, come from the freshly built agent
        weights = {**agent.state_dict(), **{k: v for k, v in weights.items() if k != WEIGHTS_ONLY_KEY}}
    try:
        agent.load_state_dict(weights)
    except (RuntimeError, ValueError, KeyError, TypeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        inputs = ", ".join(f"{k} {list(s)}" for k, s in shapes.items())
        raise ModelRefused(where, ModelRefused.NETWORK, f"its weights do not fit the {metadata.neural_network} "
                           f"network built from {metadata.source} for the inputs {inputs} ({first})",
                           "use it with the model_metadata.json and training.toml [run] observation it was trained "
                           "with (an export takes the sensors' own inputs: observation left empty), or train it "
                           "again") from None
    networks = dict(zip(inference_networks(metadata), agent.networks(), strict=False))
    return InferencePolicy(metadata, shapes, {k: net.eval() for k, net in networks.items()}, agent.policy)


def make_agent(obs, metadata, hyperparameters=None, **kwargs) -> PPO | SAC:
    """PPO or SAC per `metadata.training_algorithm`; keyword arguments go to the constructor."""
    cls = SAC if metadata.training_algorithm == "sac" else PPO
    return cls(obs, metadata, hyperparameters, **kwargs)
