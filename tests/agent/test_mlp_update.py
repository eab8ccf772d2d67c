"""The PPO update for vector networks without autograd (compiled and NumPy) against torch's autograd and Adam,
step by step."""

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


ENGINES = pytest.mark.parametrize("engine", MLPUpdater.ENGINES)


def _pair(metadata, hp, dim, hidden=(32, 32), engine="numba"):
    fast = PPO({"features": (dim,)}, metadata, hp, device="cpu", seed=3, mlp_hidden=hidden, fast_update=engine)
    slow = PPO({"features": (dim,)}, metadata, hp, device="cpu", seed=3, mlp_hidden=hidden, fast_update=False)
    assert fast._mlp is not None and fast._mlp.engine == engine and slow._mlp is None
    return fast, slow


def _weights(ppo):
    return [p.detach().numpy().copy() for p in [*ppo.policy_net.parameters(), *ppo.value_net.parameters()]]


@ENGINES
@pytest.mark.parametrize("metadata, loss_type, beta", [
    (DISCRETE, "huber", 0.01), (DISCRETE, "mean squared error", 0.5),
    (CONTINUOUS, "huber", 0.01), (CONTINUOUS, "mean squared error", 0.2)])
def test_update_without_autograd_follows_torch(metadata, loss_type, beta, engine):
    hp = Hyperparameters(num_epochs=3, batch_size=32, loss_type=loss_type, beta_entropy=beta, lr=3e-3)
    fast, slow = _pair(metadata, hp, dim=6, engine=engine)
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


@ENGINES
def test_probability_floor_blocks_the_gradient_like_torch(engine):
    hp = Hyperparameters(num_epochs=1, batch_size=16, lr=1e-3)
    fast, slow = _pair(DISCRETE, hp, dim=3, engine=engine)
    with torch.no_grad():  # a head that makes some actions far below the 1e-8 floor
        for ppo in (fast, slow):
            ppo.policy_net.head.bias.copy_(torch.tensor([30.0, 0.0, -30.0, 5.0, -5.0]))
    batch = _batch(fast, 64, 3, seed=9)
    _update_both(fast, slow, batch)
    for a, b in zip(_weights(fast), _weights(slow), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=2e-5)


@ENGINES
def test_checkpoint_round_trip_between_the_two_updates(engine):
    hp = Hyperparameters(num_epochs=2, batch_size=32)
    fast, slow = _pair(CONTINUOUS, hp, dim=4, engine=engine)
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


def test_compiled_blocks_shuffle_as_the_torch_minibatches():
    """The blocks the compiled update runs are the torch path's minibatches, in order, from the same generator."""
    hp = Hyperparameters(num_epochs=3, batch_size=32)
    fast, slow = _pair(DISCRETE, hp, dim=4)
    slow.generator.set_state(fast.generator.get_state())
    blocks = list(fast._blocks(300, 32, rows=4))  # 9 minibatches per epoch: blocks of 4, 4 and 1
    assert [len(b) for b in blocks] == [4, 4, 1] * 3
    rows = np.concatenate(blocks)
    assert np.array_equal(rows, np.stack([idx.numpy() for idx in slow._minibatches(300, 32)]))
    assert all(sorted(rows[e * 9:(e + 1) * 9].ravel()) == sorted(set(rows[e * 9:(e + 1) * 9].ravel()))
               for e in range(3))  # within an epoch no sample repeats
    fast.deadline = 0.0  # long past: one minibatch, then nothing
    assert [b.shape for b in fast._blocks(300, 32)] == [(1, 32)]


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")  # explained variance of inf
def test_compiled_update_stops_before_a_nonfinite_step():
    hp = Hyperparameters(num_epochs=2, batch_size=16)
    fast, _ = _pair(CONTINUOUS, hp, dim=4)
    fast.update(_batch(fast, 64, 4, seed=3))  # Adam has moments and a step count of 8
    batch = _batch(fast, 64, 4, seed=4)
    batch.returns[5] = np.inf  # the value loss of the minibatch that holds sample 5 is inf
    state = fast.generator.get_state()
    order = np.concatenate(list(fast._blocks(64, 16)))
    fast.generator.set_state(state)
    expected = int(np.flatnonzero((order == 5).any(axis=1))[0])  # the steps before that minibatch
    m = fast.update(batch)
    assert m["nonfinite"] == 1.0 and m["charts/gradient_steps"] == expected and fast.finite()
    assert float(fast.optimizer.state_dict()["state"][0]["step"]) == 8 + expected


@pytest.mark.parametrize("metadata", [DISCRETE, CONTINUOUS])
def test_greedy_actions_without_torch_match_the_torch_modules(metadata):
    hp = Hyperparameters(num_epochs=1, batch_size=32, lr=3e-3)
    fast, slow = _pair(metadata, hp, dim=6)
    obs = np.random.default_rng(5).normal(size=(7, 6)).astype(np.float32) * 3
    for step in range(3):  # the NumPy views follow the weights through updates and a checkpoint load
        if step == 1:
            fast.update(_batch(fast, 96, 6, seed=step))
        if step == 2:
            fast.load_state_dict(slow.state_dict())
        with torch.no_grad():
            expected = fast.policy_net.distribution({"features": torch.from_numpy(obs)}).mode().numpy()
        got = fast.policy(obs)
        assert got.shape == expected.shape
        if metadata is DISCRETE:
            assert np.array_equal(got, expected)
        else:
            np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    assert np.array_equal(fast.policy({"features": obs}), got)


def test_compiled_adam_matches_torch_and_stores_subnormal_moments_as_zero():
    from racerlab.agent import mlp_kernel

    rng = np.random.default_rng(2)
    w = rng.normal(size=6).astype(np.float32)
    g = np.array([0.5, -0.25, 1e-3, 0.0, 0.0, 2.0], dtype=np.float32)
    m = np.array([0.1, 0.0, -0.2, 1.3e-38, 0.3, 0.0], dtype=np.float32)  # 0.9 × 1.3e-38 is subnormal
    v = np.array([0.01, 0.0, 0.04, 1.1e-38, 0.09, 1e-6], dtype=np.float32)  # 0.999 × 1.1e-38 too
    param = torch.nn.Parameter(torch.from_numpy(w.copy()))
    opt = torch.optim.Adam([param], lr=1e-2, eps=1e-5)
    param.grad = torch.from_numpy(g.copy())
    opt.state[param] = {"step": torch.tensor(4.0), "exp_avg": torch.from_numpy(m.copy()),
                        "exp_avg_sq": torch.from_numpy(v.copy())}
    opt.step()
    mlp_kernel._adam(w, g, m, v, 5, 1e-2, 0.9, 0.999, 1e-5)
    np.testing.assert_allclose(w, param.detach().numpy(), rtol=1e-6)
    state = opt.state[param]
    normal = [0, 1, 2, 4, 5]
    np.testing.assert_allclose(m[normal], state["exp_avg"].numpy()[normal], rtol=1e-6)
    np.testing.assert_allclose(v[normal], state["exp_avg_sq"].numpy()[normal], rtol=1e-6)
    tiny = np.finfo(np.float32).tiny
    assert m[3] == v[3] == 0.0 and 0.0 < state["exp_avg"][3] < tiny and 0.0 < state["exp_avg_sq"][3] < tiny


def test_thread_chooser_runs_the_rest_of_each_period_on_the_faster_count(monkeypatch):
    from racerlab.agent import common

    clock = [0.0]
    monkeypatch.setattr(common.time, "perf_counter", lambda: clock[0])
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    chooser = common.ThreadChooser(2, every=4)
    seconds = {1: 0.1, 2: 0.15}  # 2 threads a little slower: periods stay 4 steps
    used = []
    try:
        for step in range(22):
            if step == 8:
                seconds = {1: 0.15, 2: 0.1}  # the other core is free now
            if step == 12:
                seconds = {1: 0.1, 2: 0.5}  # and busy again, badly: the trials grow rarer
            with chooser as n:
                used.append(n)
                assert torch.get_num_threads() == n
                clock[0] += seconds[n] + (5.0 if step == 0 else 0.0)  # the first step (warm-up) is not counted
        chooser.restore()
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    # each period tries 1 then 2 threads and runs the faster; after a lopsided trial the period doubles
    assert used == [2,  1, 2, 1, 1,  1, 2, 1, 1,  1, 2, 2, 2,  1, 2, 1, 1, 1, 1, 1, 1,  1]


def test_torch_update_gives_the_thread_count_back():
    camera = ModelMetadata(FIVE, ("FRONT_FACING_CAMERA",), "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW")
    ppo = PPO({"camera": (40, 60, 1)}, camera, Hyperparameters(num_epochs=1, batch_size=8), device="cpu")
    before = torch.get_num_threads()
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 256, size=(48, 40, 60, 1), dtype=np.uint8)
    actions, logp, values = ppo.act(obs)
    greedy = [ppo.policy(obs[:5]) for _ in range(4)]  # acting and evaluating choose their threads too
    assert torch.get_num_threads() == before and all(np.array_equal(g, greedy[0]) for g in greedy)
    m = ppo.update(PPOBatch(obs, actions, logp, values, rng.normal(size=48).astype(np.float32),
                            rng.normal(size=48).astype(np.float32)))
    assert m["charts/gradient_steps"] == 6 and torch.get_num_threads() == before


@pytest.mark.parametrize("metadata", [DISCRETE, CONTINUOUS])
def test_compiled_update_follows_torch_on_a_deeper_chain_of_uneven_widths(metadata):
    hp = Hyperparameters(num_epochs=2, batch_size=16, lr=3e-3)
    fast, slow = _pair(metadata, hp, dim=5, hidden=(24, 40, 8))
    assert len(fast._mlp.policy.linears) == 4
    for it in range(2):
        m_fast, m_slow = _update_both(fast, slow, _batch(fast, 80, 5, seed=10 + it))
        assert m_fast["losses/value"] == pytest.approx(m_slow["losses/value"], rel=1e-3)
    for a, b in zip(_weights(fast), _weights(slow), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=2e-5)
