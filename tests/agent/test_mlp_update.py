"""The NumPy PPO update for vector networks against torch's autograd and Adam, step by step."""

import numpy as np
import pytest
import torch

from racerlab.agent.mlp_update import MLPUpdater, VectorChain
from racerlab.agent.ppo import PPO, PPOBatch
from racerlab.model.hyperparameters import Hyperparameters
from racerlab.model.metadata import ContinuousActions, DiscreteActions, ModelMetadata

FIVE = DiscreteActions((-30.0, -15.0, 0.0, 15.0, 30.0), (1.0, 2.0, 3.0, 2.0, 1.0))
DISCRETE = ModelMetadata(FIVE, ("FEATURES",), "MLP")
CONTINUOUS = ModelMetadata(ContinuousActions(-30, 30, 1, 3), ("FEATURES",), "MLP")
LIDAR = ModelMetadata(FIVE, ("LIDAR",), "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW")


def _batch(ppo, n, dim, seed):
    """A batch acted by the agent itself (so the ratios start at 1 and move), with skewed advantages."""
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n, dim)).astype(np.float32) * 2
    actions, logp, values = ppo.act(obs)
    adv = (rng.normal(size=n) * 3 + 1).astype(np.float32)
    returns = (rng.normal(size=n) * 2).astype(np.float32)  # beyond ±1 from V: Huber's linear part is used
    return PPOBatch(obs, actions, logp, values, adv, returns)


def _update_both(fast, slow, batch):
    slow.generator.set_state(fast.generator.get_state())  # the same minibatch shuffles
    return fast.update(batch), slow.update(batch)


def _pair(metadata, hp, dim, hidden=(32, 32)):
    fast = PPO({"features": (dim,)}, metadata, hp, device="cpu", seed=3, mlp_hidden=hidden)
    slow = PPO({"features": (dim,)}, metadata, hp, device="cpu", seed=3, mlp_hidden=hidden, fast_update=False)
    assert fast._mlp is not None and slow._mlp is None
    return fast, slow


def _weights(ppo):
    return [p.detach().numpy().copy() for p in [*ppo.policy_net.parameters(), *ppo.value_net.parameters()]]


@pytest.mark.parametrize("metadata, loss_type, beta", [
    (DISCRETE, "huber", 0.01), (DISCRETE, "mean squared error", 0.5),
    (CONTINUOUS, "huber", 0.01), (CONTINUOUS, "mean squared error", 0.2)])
def test_numpy_update_follows_torch(metadata, loss_type, beta):
    hp = Hyperparameters(num_epochs=3, batch_size=32, loss_type=loss_type, beta_entropy=beta, lr=3e-3)
    fast, slow = _pair(metadata, hp, dim=6)
    for it in range(3):  # several iterations: Adam's moments and step count carry over between updates
        batch = _batch(fast, 200, 6, seed=it)
        m_fast, m_slow = _update_both(fast, slow, batch)
        for key in ("losses/policy", "losses/value", "losses/entropy", "losses/approx_kl", "losses/clipfrac",
                    "charts/gradient_steps"):
            assert m_fast[key] == pytest.approx(m_slow[key], rel=1e-3, abs=1e-5), key
        for a, b in zip(_weights(fast), _weights(slow), strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-3, atol=2e-5)
    assert m_fast["losses/clipfrac"] > 0  # the lr is large enough for the clip to matter
    s_fast, s_slow = fast.optimizer.state_dict()["state"], slow.optimizer.state_dict()["state"]
    assert float(s_fast[0]["step"]) == float(s_slow[0]["step"]) == 3 * 3 * 6


def test_probability_floor_blocks_the_gradient_like_torch():
    hp = Hyperparameters(num_epochs=1, batch_size=16, lr=1e-3)
    fast, slow = _pair(DISCRETE, hp, dim=3)
    with torch.no_grad():  # a head that makes some actions far below the 1e-8 floor
        for ppo in (fast, slow):
            ppo.policy_net.head.bias.copy_(torch.tensor([30.0, 0.0, -30.0, 5.0, -5.0]))
    batch = _batch(fast, 64, 3, seed=9)
    _update_both(fast, slow, batch)
    for a, b in zip(_weights(fast), _weights(slow), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=2e-5)


def test_checkpoint_round_trip_between_the_two_updates():
    hp = Hyperparameters(num_epochs=2, batch_size=32)
    fast, slow = _pair(CONTINUOUS, hp, dim=4)
    fast.update(_batch(fast, 100, 4, seed=1))
    slow.load_state_dict(fast.state_dict())  # a torch-updated agent resumes from a NumPy-updated state
    batch = _batch(fast, 100, 4, seed=2)
    _update_both(fast, slow, batch)
    for a, b in zip(_weights(fast), _weights(slow), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=2e-5)


def test_chain_covers_vector_networks_only():
    lidar = PPO({"lidar": (64,)}, LIDAR, device="cpu")
    assert lidar._mlp is not None and len(VectorChain.of(lidar.policy_net).linears) == 4  # 256, 256, 512, head
    camera = PPO({"camera": (40, 60, 1)}, ModelMetadata(FIVE, ("FRONT_FACING_CAMERA",),
                                                         "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"), device="cpu")
    assert camera._mlp is None
    assert not MLPUpdater.covers(lidar.policy_net, lidar.value_net, torch.device("meta"))


def test_learner_threads_one_for_vectors_all_cores_for_convolutions(monkeypatch):
    from racerlab.agent.common import learner_threads

    monkeypatch.setattr("os.cpu_count", lambda: 8)
    vector = PPO({"features": (6,)}, DISCRETE, device="cpu")
    camera = PPO({"camera": (40, 60, 1)}, ModelMetadata(FIVE, ("FRONT_FACING_CAMERA",),
                                                         "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"), device="cpu")
    assert learner_threads(vector.networks()) == 1
    assert learner_threads(camera.networks(), load=0.5) == 8
    assert learner_threads(vector.networks(), requested=3) == 3


def test_openmp_threads_sleep_while_waiting_unless_the_user_says_otherwise():
    import os
    import subprocess
    import sys

    code = "import racerlab, os; print(os.environ['OMP_WAIT_POLICY'])"
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "PASSIVE"
    out = subprocess.run([sys.executable, "-c", code], env={**env, "OMP_WAIT_POLICY": "ACTIVE"},
                         capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "ACTIVE"


def test_checkpoint_of_other_widths_is_a_one_line_error():
    from racerlab.errors import ConfigError

    old = PPO({"features": (6,)}, DISCRETE, device="cpu", mlp_hidden=(256, 256))
    new = PPO({"features": (6,)}, DISCRETE, device="cpu")
    with pytest.raises(ConfigError, match=r"has shape \(256, 6\), this network's is \(64, 6\)"):
        new.load_state_dict(old.state_dict())
