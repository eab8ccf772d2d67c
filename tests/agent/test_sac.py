"""SAC: the soft target by hand, the replay memory, an update that learns a toy, checkpoints."""

import numpy as np
import pytest
import torch

from racerlab.agent import make_agent
from racerlab.agent.ppo import PPO
from racerlab.agent.sac import SAC, ReplayBuffer, policy_loss, soft_q_target
from racerlab.model import ContinuousActions, Hyperparameters, ModelMetadata

SAC_MLP = ModelMetadata(ContinuousActions(-30, 30, 1, 3), ("FEATURES",), "MLP", "sac")
TARGET = np.array([0.5, -0.2], np.float32)


def test_soft_q_target_by_hand():
    # y = r + γ(1 − done)(min(Q1', Q2') − α log π'): 1 + 0.9·(2 − 0.2·(−1)) = 2.98; terminated: y = r
    y = soft_q_target(torch.tensor([1.0, 1.0]), torch.tensor([0.0, 1.0]), torch.tensor([2.0, 2.0]),
                      torch.tensor([3.0, 3.0]), torch.tensor([-1.0, -1.0]), gamma=0.9, alpha=0.2)
    assert y.tolist() == pytest.approx([2.98, 1.0])
    assert policy_loss(torch.tensor([1.0]), torch.tensor([2.0]), torch.tensor([-1.0]), 0.2).item() \
        == pytest.approx(-0.2 - 1.0)


def test_replay_buffer_wraps_and_keeps_dtypes():
    buf = ReplayBuffer(capacity=5)
    for i in range(3):  # 3 batches of 2: the ring overwrites the oldest
        obs = {"camera": np.full((2, 4, 4, 1), i, np.uint8), "lidar": np.full((2, 3), i, np.float32)}
        buf.add(obs, np.zeros((2, 2)), np.full(2, i), obs, np.zeros(2, bool))
    assert len(buf) == 5 and buf.pos == 1
    assert buf.data["obs/camera"].dtype == np.uint8 and buf.data["rewards"].tolist() == [2, 0, 1, 1, 2]
    s = buf.sample(8, np.random.default_rng(0))
    assert s["obs/camera"].shape == (8, 4, 4, 1) and s["next_obs/lidar"].shape == (8, 3)


def _fill(sac, n=1024, seed=0):
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n, 3)).astype(np.float32)
    actions = rng.uniform(-1, 1, size=(n, 2)).astype(np.float32)
    rewards = -np.sum((actions - TARGET) ** 2, 1)
    sac.observe(obs, actions, rewards, obs, np.ones(n, bool))


def test_sac_update_reduces_q_loss_and_finds_the_target():
    sac = SAC((3,), SAC_MLP, Hyperparameters(batch_size=128, lr=1e-3), device="cpu", seed=0)
    _fill(sac)
    first = sac.update(20)["losses/q"]
    for _ in range(8):
        last = sac.update(25)
    assert last["losses/q"] < 0.1 * first and last["nonfinite"] == 0.0 and sac.finite()
    greedy = sac.act(np.random.default_rng(1).normal(size=(64, 3)).astype(np.float32), greedy=True)
    assert np.abs(greedy.mean(0) - TARGET).max() < 0.15
    assert sac.gradient_steps == 220


def test_sac_act_is_bounded_and_greedy_is_deterministic():
    sac = SAC({"features": (3,)}, SAC_MLP, device="cpu")
    obs = np.random.default_rng(0).normal(size=(500, 3)).astype(np.float32)
    a = sac.act(obs)
    assert a.shape == (500, 2) and np.abs(a).max() < 1.0 and a.std() > 0.1
    assert np.array_equal(sac.act(obs, greedy=True), sac.act(obs, greedy=True))


def test_sac_state_dict_round_trip():
    a = SAC((3,), SAC_MLP, Hyperparameters(batch_size=32), device="cpu", seed=1)
    _fill(a, 256)
    a.update(5)
    a.lr = 1e-4
    b = SAC((3,), SAC_MLP, Hyperparameters(batch_size=32), device="cpu", seed=2)
    b.load_state_dict(a.state_dict())
    obs = np.random.default_rng(3).normal(size=(16, 3)).astype(np.float32)
    assert np.array_equal(a.act(obs), b.act(obs)) and b.lr == 1e-4
    _fill(b, 256)  # same transitions, same sampling state: the next update matches
    assert a.update(3)["losses/q"] == b.update(3)["losses/q"]
    with pytest.raises(ValueError, match="SAC state"):
        b.load_state_dict({"format": "racerlab.ppo/1"})


def test_update_needs_data():
    with pytest.raises(ValueError, match="before any transition"):
        SAC((3,), SAC_MLP, device="cpu").update(1)


def test_make_agent_dispatches_on_the_algorithm():
    assert isinstance(make_agent((3,), SAC_MLP, device="cpu"), SAC)
    ppo_md = ModelMetadata(ContinuousActions(-30, 30, 1, 3), ("FEATURES",), "MLP")
    assert isinstance(make_agent((3,), ppo_md, device="cpu"), PPO)
