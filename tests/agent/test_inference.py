"""`inference_policy`: a checkpoint's weights as the greedy actions the trained agent itself takes, its bare
networks in eval mode, and one refusal for weights that do not fit the network."""

import numpy as np
import pytest
import torch

from racerlab.agent import inference_policy, make_agent
from racerlab.errors import ModelRefused
from racerlab.model import ContinuousActions, DiscreteActions, ModelMetadata

DISCRETE = ModelMetadata(DiscreteActions((-30.0, 0.0, 30.0), (1.0, 1.0, 1.0)), ("FEATURES",), "MLP", "clipped_ppo")
SAC = ModelMetadata(ContinuousActions(-30, 30, 1, 3), ("FEATURES",), "MLP", "sac")
CAMERA = ModelMetadata(DiscreteActions((-30.0, 30.0), (1.0, 1.0)), ("FRONT_FACING_CAMERA",),
                       "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "clipped_ppo")


def _trained(meta, shapes, seed=3):
    """An agent whose weights are not its initial ones (inference_policy builds its own agent from seed 0)."""
    agent = make_agent(shapes, meta, device="cpu", seed=seed)
    with torch.no_grad():
        for net in agent.networks():
            for p in net.parameters():
                p.add_(0.3 * torch.randn(p.shape, generator=torch.Generator().manual_seed(seed)))
    return agent


@pytest.mark.parametrize("meta,shapes,names", [(DISCRETE, {"features": (12,)}, ["policy", "value"]),
                                               (SAC, {"features": (12,)}, ["actor"]),
                                               (CAMERA, {"camera": (120, 160, 1)}, ["policy", "value"])])
def test_the_policy_takes_the_trained_agents_greedy_actions(meta, shapes, names):
    agent = _trained(meta, shapes)
    policy = inference_policy(shapes, meta, agent.state_dict(), where="m/checkpoints/1_Step-10.pt")
    rng = np.random.default_rng(0)
    obs = {k: (rng.integers(0, 256, (6, *s)).astype(np.uint8) if len(s) == 3 else
               rng.normal(size=(6, *s)).astype(np.float32)) for k, s in shapes.items()}
    np.testing.assert_array_equal(policy(obs), agent.policy(obs))
    np.testing.assert_array_equal(policy.policy(obs), agent.policy(obs))  # stands in for an agent
    assert sorted(policy.networks) == sorted(names) and policy.shapes == shapes and policy.metadata is meta
    assert all(not net.training for net in policy.networks.values())
    for name, net in policy.networks.items():  # the bare networks hold the checkpoint's weights
        for key, value in net.state_dict().items():
            assert torch.equal(value, agent.state_dict()[name][key])


def test_weights_that_do_not_fit_are_refused_in_one_line():
    state = _trained(DISCRETE, {"features": (12,)}).state_dict()
    with pytest.raises(ModelRefused) as err:  # a features network of 12 inputs read with 14
        inference_policy({"features": (14,)}, DISCRETE, state, where="m/checkpoints/1_Step-10.pt")
    text = str(err.value)
    assert err.value.reason == ModelRefused.NETWORK and "\n" not in text
    assert text.startswith("m/checkpoints/1_Step-10.pt: its weights do not fit the MLP network built from "
                           "model_metadata.json for the inputs features [14] (")
    assert text.endswith("or train it again")
    with pytest.raises(ModelRefused, match=r"weights do not fit the DEEP_CONVOLUTIONAL_NETWORK_SHALLOW network .* "
                                           r"camera \[120, 160, 1\]"):
        inference_policy({"camera": (120, 160, 1)}, CAMERA, state, where="m/x.pt")  # an MLP's weights for a CNN
    with pytest.raises(ModelRefused, match="weights do not fit"):
        inference_policy({"features": (12,)}, SAC, state, where="m/x.pt")  # PPO's weights for SAC
