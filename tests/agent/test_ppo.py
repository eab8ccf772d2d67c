"""Clipped PPO: GAE and the loss on hand-worked numbers, minibatching, checkpoints, and a toy that learns."""

import io
import math

import numpy as np
import pytest
import torch

from racerlab.agent.ppo import (
    PPO,
    PPOBatch,
    compute_gae,
    episode_next_values,
    explained_variance,
    make_batch,
    minibatch_size,
    ppo_losses,
)
from racerlab.errors import ConfigError
from racerlab.model import ContinuousActions, DiscreteActions, Hyperparameters, ModelMetadata

THREE = DiscreteActions((-30.0, 0.0, 30.0), (1.0, 1.0, 1.0))
MLP_DISCRETE = ModelMetadata(THREE, ("FEATURES",), "MLP")
MLP_CONTINUOUS = ModelMetadata(ContinuousActions(-30, 30, 1, 3), ("FEATURES",), "MLP")


# -- GAE ---------------------------------------------------------------------------------------------

def test_gae_termination_vs_truncation_by_hand():
    # Two cars, 3 steps, identical except the last step: car 0 terminates (bootstrap 0), car 1 is
    # truncated (bootstrap with V(final obs) = 0.2). γ = 0.9, λ = 0.5, so γλ = 0.45.
    rewards = np.ones((3, 2))
    values = np.array([[0.5, 0.5], [0.4, 0.4], [0.3, 0.3]])
    next_values = np.array([[0.4, 0.4], [0.3, 0.3], [0.2, 0.2]])
    terminated = np.array([[0, 0], [0, 0], [1, 0]], bool)
    truncated = np.array([[0, 0], [0, 0], [0, 1]], bool)
    adv, ret = compute_gae(rewards, values, next_values, terminated, truncated, gamma=0.9, lam=0.5)
    # car 0: δ2 = 1 − 0.3 = 0.7; δ1 = 1 + 0.27 − 0.4 = 0.87, A1 = 0.87 + 0.45·0.7 = 1.185;
    #        δ0 = 1 + 0.36 − 0.5 = 0.86, A0 = 0.86 + 0.45·1.185 = 1.39325
    # car 1: δ2 = 1 + 0.18 − 0.3 = 0.88; A1 = 0.87 + 0.45·0.88 = 1.266; A0 = 0.86 + 0.45·1.266 = 1.4297
    assert np.allclose(adv[:, 0], [1.39325, 1.185, 0.7])
    assert np.allclose(adv[:, 1], [1.4297, 1.266, 0.88])
    assert np.allclose(ret, adv + values)
    assert adv.dtype == np.float32


def test_gae_unfinished_tail_bootstraps_like_truncation():
    kw = dict(rewards=[[1.0]], values=[[0.5]], next_values=[[2.0]], gamma=0.9, lam=0.95)
    open_end, _ = compute_gae(terminated=[[False]], truncated=[[False]], **kw)
    cut, _ = compute_gae(terminated=[[False]], truncated=[[True]], **kw)
    assert open_end[0, 0] == pytest.approx(1 + 0.9 * 2 - 0.5) and cut[0, 0] == open_end[0, 0]


def test_gae_on_flat_whole_episodes_by_hand():
    # Episode A: steps 0-1, terminated. Episode B: steps 2-3, truncated with V(final obs) = 0.7.
    rewards = np.array([1.0, 2.0, 0.5, 1.0])
    values = np.array([0.2, 0.4, 0.1, 0.3])
    terminated = np.array([0, 1, 0, 0], bool)
    truncated = np.array([0, 0, 0, 1], bool)
    next_values = episode_next_values(values, terminated | truncated, end_values=[0.0, 0.7])
    assert np.allclose(next_values, [0.4, 0.0, 0.3, 0.7])
    adv, ret = compute_gae(rewards, values, next_values, terminated, truncated, gamma=0.9, lam=0.5)
    # B: A3 = 1 + 0.63 − 0.3 = 1.33; A2 = (0.5 + 0.27 − 0.1) + 0.45·1.33 = 1.2685
    # A: A1 = 2 − 0.4 = 1.6 (no bootstrap); A0 = (1 + 0.36 − 0.2) + 0.45·1.6 = 1.88 (does not see B)
    assert np.allclose(adv, [1.88, 1.6, 1.2685, 1.33])
    assert np.allclose(ret, [2.08, 2.0, 1.3685, 1.63])
    with pytest.raises(ValueError, match="completed episode"):
        episode_next_values(values, [True, False, False, False], [0.0])


def test_make_batch_flattens_time_major():
    t, b = 3, 2
    obs = {"features": np.arange(t * b * 4, dtype=np.float32).reshape(t, b, 4)}
    z = np.zeros((t, b))
    batch = make_batch(obs, np.ones((t, b), np.int64), z, z, np.ones((t, b)), z, z.astype(bool),
                       z.astype(bool), gamma=0.9)
    assert batch.obs["features"].shape == (6, 4) and batch.actions.shape == (6,)
    assert np.array_equal(batch.obs["features"][1], obs["features"][0, 1])  # row = t·B + b
    assert batch.advantages.shape == (6,) and batch.returns.shape == (6,)


# -- the loss ----------------------------------------------------------------------------------------

def _loss_example(loss_type):
    old = torch.zeros(5)
    new = torch.tensor([math.log(1.5), math.log(0.5), math.log(0.5), math.log(1.5), 0.0], requires_grad=True)
    adv = torch.tensor([1.0, -1.0, 1.0, -1.0, 2.0])
    returns = torch.tensor([0.5, 2.0, -3.0, 0.0, 0.0])
    out = ppo_losses(new, old, adv, torch.zeros(5), returns, torch.full((5,), 0.5),
                     clip=0.2, loss_type=loss_type, beta_entropy=0.01)
    return new, out


def test_ppo_loss_by_hand():
    new, out = _loss_example("huber")
    # min(r·A, clip(r)·A) per sample: 1.2 (clipped above), −0.8 (clipped below), 0.5 and −1.5
    # (the pessimistic unclipped side), 2 (r = 1): mean 0.28, and the loss is its negative
    assert out.pg_loss.item() == pytest.approx(-0.28)
    assert out.v_loss.item() == pytest.approx((0.125 + 1.5 + 2.5) / 5)  # Huber δ=1: ½x² or |x| − ½
    assert out.entropy.item() == pytest.approx(0.5)
    assert out.loss.item() == pytest.approx(-0.28 + 0.825 - 0.01 * 0.5)
    assert out.clipfrac.item() == pytest.approx(0.8)
    kl = 2 * (0.5 - math.log(1.5)) + 2 * (-0.5 - math.log(0.5))
    assert out.approx_kl.item() == pytest.approx(kl / 5)
    # clipped samples get no policy gradient; the others get −A·r/5
    out.pg_loss.backward()
    assert new.grad.tolist() == pytest.approx([0.0, 0.0, -0.1, 0.3, -0.4])


def test_ppo_loss_mse():
    _, out = _loss_example("mean squared error")
    assert out.v_loss.item() == pytest.approx((0.25 + 4 + 9) / 5)


@pytest.mark.parametrize("n, bs, mb", [(1000, 64, 64), (64, 64, 64), (50, 64, 32), (33, 64, 32),
                                       (1, 64, 1), (0, 64, 0)])
def test_minibatch_size_power_of_two_rule(n, bs, mb):
    assert minibatch_size(n, bs) == mb


def test_explained_variance():
    y = np.array([1.0, 2.0, 3.0])
    assert explained_variance(y, y) == 1.0 and explained_variance(np.zeros(3), y) == pytest.approx(0.0)
    assert explained_variance(y[::-1], y) == pytest.approx(1 - (8 / 3) / (2 / 3))
    assert explained_variance(y, np.ones(3)) == 0.0


# -- the agent ---------------------------------------------------------------------------------------

def _random_batch(n, dim=4, seed=0, continuous=False):
    rng = np.random.default_rng(seed)
    actions = rng.normal(size=(n, 2)).astype(np.float32) if continuous else rng.integers(0, 3, n)
    return PPOBatch(rng.normal(size=(n, dim)).astype(np.float32), actions,
                    np.full(n, -1.1, np.float32), np.zeros(n, np.float32),
                    rng.normal(size=n).astype(np.float32), rng.normal(size=n).astype(np.float32))


@pytest.mark.parametrize("n, steps", [(200, 3 * 2), (100, 1 * 2), (50, 1 * 2), (63, 1 * 2)])
def test_update_runs_int_n_over_batch_minibatches_per_epoch(n, steps):
    ppo = PPO((4,), MLP_DISCRETE, Hyperparameters(num_epochs=2), device="cpu")
    m = ppo.update(_random_batch(n))
    assert m["charts/gradient_steps"] == steps
    assert m["charts/minibatch_size"] == minibatch_size(n, 64)
    for key in ("losses/policy", "losses/value", "losses/entropy", "losses/approx_kl", "losses/clipfrac",
                "losses/explained_variance"):
        assert math.isfinite(m[key])
    assert m["nonfinite"] == 0.0 and ppo.finite()


def test_act_shapes_and_greedy():
    ppo = PPO({"features": (4,)}, MLP_DISCRETE, device="cpu")
    obs = np.random.default_rng(0).normal(size=(8, 4)).astype(np.float32)
    a, logp, v = ppo.act(obs)
    assert a.shape == (8,) and a.dtype == np.int64 and logp.shape == (8,) and v.shape == (8,)
    assert ppo.env_steps == 8
    g1, _, _ = ppo.act(obs, greedy=True)
    g2, _, _ = ppo.act({"features": obs}, greedy=True)
    assert np.array_equal(g1, g2) and ppo.env_steps == 8  # evaluation does not advance ε
    assert np.allclose(ppo.value(obs), v)


def test_continuous_act_returns_unclipped_samples():
    ppo = PPO((4,), MLP_CONTINUOUS, device="cpu")
    obs = np.zeros((4000, 4), np.float32)
    a, logp, _ = ppo.act(obs)
    assert a.shape == (4000, 2) and np.abs(a).max() > 1.5  # std 1 at the start
    assert np.allclose(ppo.act(obs, greedy=True)[0], ppo.act(obs, greedy=True)[0])


def test_e_greedy_schedule_follows_env_steps():
    hp = Hyperparameters(exploration_type="e-greedy", e_greedy_value=0.05, epsilon_steps=100)
    ppo = PPO((4,), MLP_DISCRETE, hp, device="cpu")
    assert ppo.epsilon == 1.0
    ppo.act(np.zeros((50, 4), np.float32))
    assert ppo.epsilon == pytest.approx(0.525)
    ppo.act(np.zeros((80, 4), np.float32))
    assert ppo.epsilon == pytest.approx(0.05)
    assert PPO((4,), MLP_DISCRETE, device="cpu").epsilon == 0.0


def test_additive_noise_refused_for_discrete():
    hp = Hyperparameters(exploration_type="additive_noise", source="m/hyperparameters.json")
    with pytest.raises(ConfigError, match="m/hyperparameters.json: exploration_type"):
        PPO((4,), MLP_DISCRETE, hp, device="cpu")
    PPO((4,), MLP_CONTINUOUS, hp, device="cpu")  # continuous ignores it, as AWS


def test_state_dict_round_trip_gives_identical_actions():
    hp = Hyperparameters(lr=1e-3)
    a = PPO((4,), MLP_DISCRETE, hp, device="cpu", seed=1)
    a.update(_random_batch(128))
    a.lr = 5e-4
    buf = io.BytesIO()
    torch.save(a.state_dict(), buf)
    buf.seek(0)
    b = PPO((4,), MLP_DISCRETE, hp, device="cpu", seed=99)
    b.load_state_dict(torch.load(buf, weights_only=False))
    assert b.lr == 5e-4 and b.env_steps == a.env_steps
    obs = np.random.default_rng(3).normal(size=(256, 4)).astype(np.float32)
    for greedy in (True, False):
        xa, la, va = a.act(obs, greedy)
        xb, lb, vb = b.act(obs, greedy)
        assert np.array_equal(xa, xb) and np.array_equal(la, lb) and np.array_equal(va, vb)
    # the optimizer state came along too: one more identical update keeps them identical
    batch = _random_batch(128, seed=5)
    a.update(batch), b.update(batch)
    assert np.array_equal(a.act(obs, True)[1], b.act(obs, True)[1])


def test_state_dict_is_a_snapshot_for_the_nan_guard():
    ppo = PPO((4,), MLP_DISCRETE, device="cpu")
    ppo.update(_random_batch(128))
    good = ppo.state_dict()
    obs = np.random.default_rng(3).normal(size=(64, 4)).astype(np.float32)
    before = ppo.act(obs, greedy=True)[1]
    for seed in range(3):  # training on must not change the snapshot, nor loading it twice
        ppo.update(_random_batch(128, seed=seed))
    ppo.load_state_dict(good)
    ppo.update(_random_batch(128, seed=9))
    ppo.load_state_dict(good)
    assert np.array_equal(ppo.act(obs, greedy=True)[1], before)


def test_same_seed_same_weights():
    a, b = (PPO((4,), MLP_DISCRETE, device="cpu", seed=7) for _ in range(2))
    assert all(torch.equal(p, q) for p, q in zip(a.policy_net.parameters(), b.policy_net.parameters(),
                                                 strict=True))


def test_nonfinite_is_reported_and_not_applied():
    ppo = PPO((4,), MLP_DISCRETE, device="cpu")
    before = [p.clone() for p in ppo.policy_net.parameters()]
    batch = _random_batch(64)
    batch.obs[0, 0] = np.nan
    m = ppo.update(batch)
    assert m["nonfinite"] == 1.0 and m["charts/gradient_steps"] == 0 and ppo.finite()
    assert all(torch.equal(p, q) for p, q in zip(before, ppo.policy_net.parameters(), strict=True))
    with torch.no_grad():
        next(ppo.value_net.parameters())[0, 0] = float("inf")
    assert not ppo.finite()


def test_lr_is_settable_for_the_nan_guard():
    ppo = PPO((4,), MLP_DISCRETE, Hyperparameters(lr=3e-4), device="cpu")
    ppo.lr = ppo.lr / 2
    assert ppo.lr == 1.5e-4 and all(g["lr"] == 1.5e-4 for g in ppo.optimizer.param_groups)


def test_auto_device_is_cpu_without_cuda():
    ppo = PPO((4,), MLP_DISCRETE)
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert ppo.device.type == expected and next(ppo.policy_net.parameters()).device.type == expected


# -- learning ------------------------------------------------------------------------------------------

def _bandit_accuracy(ppo, rng, n=512):
    obs = rng.normal(size=(n, 4)).astype(np.float32)
    return float(np.mean(ppo.act(obs, greedy=True)[0] == obs[:, :3].argmax(1)))


def test_ppo_learns_a_contextual_bandit():
    # One-step episodes: reward 1 when the action is the index of the largest of the first 3 features.
    rng = np.random.default_rng(0)
    ppo = PPO((4,), MLP_DISCRETE, Hyperparameters(lr=1e-3, num_epochs=4), device="cpu", seed=0)
    before = _bandit_accuracy(ppo, np.random.default_rng(1))
    for _ in range(25):
        obs = rng.normal(size=(256, 4)).astype(np.float32)
        actions, log_probs, values = ppo.act(obs)
        rewards = (actions == obs[:, :3].argmax(1)).astype(np.float32)
        done = np.ones(256, bool)
        batch = make_batch(obs, actions, log_probs, values, rewards, np.zeros(256), done, ~done, gamma=0.99)
        ppo.update(batch)
    after = _bandit_accuracy(ppo, np.random.default_rng(1))
    assert before < 0.5 and after > 0.9


def test_ppo_learns_a_continuous_target():
    # reward −‖a − a*‖² with a* = (0.5·sign(x0), −0.3): the greedy (mean) action must approach a*
    rng = np.random.default_rng(0)
    ppo = PPO((4,), MLP_CONTINUOUS, Hyperparameters(lr=1e-3, num_epochs=4), device="cpu", seed=0)

    def error(obs):
        target = np.stack([0.5 * np.sign(obs[:, 0]), np.full(len(obs), -0.3)], 1)
        return target, float(np.mean(np.sum((ppo.act(obs, greedy=True)[0] - target) ** 2, 1)))

    test_obs = np.random.default_rng(1).normal(size=(512, 4)).astype(np.float32)
    _, before = error(test_obs)
    for _ in range(50):
        obs = rng.normal(size=(256, 4)).astype(np.float32)
        actions, log_probs, values = ppo.act(obs)
        target, _ = error(obs)
        rewards = -np.sum((actions - target) ** 2, 1)
        done = np.ones(256, bool)
        ppo.update(make_batch(obs, actions, log_probs, values, rewards, np.zeros(256), done, ~done, 0.99))
    _, after = error(test_obs)
    assert after < 0.2 * before and after < 0.08


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_round_trip():
    ppo = PPO((4,), MLP_DISCRETE, device="cuda")
    obs = np.zeros((8, 4), np.float32)
    a, logp, v = ppo.act(obs)
    assert isinstance(a, np.ndarray) and ppo.policy_net.head.weight.is_cuda
    ppo.update(_random_batch(128))
    cpu = PPO((4,), MLP_DISCRETE, device="cpu")
    cpu.load_state_dict(ppo.state_dict())
    assert np.array_equal(cpu.act(obs, True)[0], ppo.act(obs, True)[0])


# -- the return scale (RETURN_SCALE_WEIGHT) ----------------------------------------------------------

def _rollout(ppo, obs, rewards, terminated, truncated):
    """A `train.rollout.Rollout`'s fields that `PPO.learn` reads, from `explore` on `obs`."""
    from types import SimpleNamespace

    actions, record = ppo.explore(obs)
    return SimpleNamespace(obs=obs, actions=actions, record=record, rewards=np.asarray(rewards, np.float32),
                           terminated=np.asarray(terminated, bool), truncated=np.asarray(truncated, bool),
                           final_obs=obs[np.asarray(truncated, bool)])


def test_return_scale_is_the_rms_discounted_return_then_a_running_blend():
    # two episodes, γ = 0.5: [1, 1] terminated -> returns 1.5, 1; [2] truncated -> 2 (the scale bootstraps 0)
    # RMS = sqrt((2.25 + 1 + 4) / 3) = sqrt(2.41667) = 1.55456; the second rollout's RMS 2 × 1.55456 blends in
    # with weight 0.1: 1.55456 + 0.1 × 1.55456 = 1.71002
    ppo = PPO((4,), MLP_CONTINUOUS, Hyperparameters(discount_factor=0.5), device="cpu", seed=0)
    obs = np.random.default_rng(0).normal(size=(3, 4)).astype(np.float32)
    ends = dict(terminated=[False, True, False], truncated=[False, False, True])
    metrics = ppo.learn(_rollout(ppo, obs, [1.0, 1.0, 2.0], **ends))
    assert ppo.return_scale == pytest.approx(1.55456, abs=1e-5) == metrics["learner/return_scale"]
    ppo.learn(_rollout(ppo, obs, [2.0, 2.0, 4.0], **ends))
    assert ppo.return_scale == pytest.approx(1.71002, abs=1e-5)
    # act and value speak the reward's units: the value net's output times the scale
    with torch.no_grad():
        raw = ppo.value_net({ppo.keys[0]: torch.as_tensor(obs)}).numpy()
    assert np.allclose(ppo.value(obs), raw * 1.71002, rtol=1e-5)
    assert np.allclose(ppo.act(obs)[2], raw * 1.71002, rtol=1e-5)
    again = PPO((4,), MLP_CONTINUOUS, device="cpu", seed=1)
    again.load_state_dict(ppo.state_dict())
    assert again.return_scale == ppo.return_scale


@pytest.mark.parametrize("fast_update", [True, False])
def test_a_reward_a_hundred_times_larger_learns_the_same_policy(fast_update):
    # a racer's reward scale (0-1 per step, or bonuses of 1 000) should not change what is learnt: with the
    # returns scaled, two agents fed r and 100·r end with the same policy weights after three iterations
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(96, 4)).astype(np.float32)
    ends = np.zeros(96, bool)
    ends[31::32] = True  # three episodes of 32 steps, cut by a step limit
    agents = [PPO((4,), MLP_CONTINUOUS, Hyperparameters(num_epochs=2), device="cpu", seed=0,
                  fast_update=fast_update) for _ in range(2)]
    for _ in range(3):
        for agent, k in zip(agents, (1.0, 100.0), strict=True):
            ro = _rollout(agent, obs, [], np.zeros(96, bool), ends)
            ro.rewards = (k * -np.sum((ro.actions - 0.3) ** 2, 1)).astype(np.float32)
            agent.learn(ro)
    for a, b in zip(agents[0].policy_net.parameters(), agents[1].policy_net.parameters(), strict=True):
        assert torch.allclose(a, b, atol=1e-4)
    assert agents[1].return_scale == pytest.approx(100 * agents[0].return_scale, rel=1e-5)


def test_the_learning_rate_follows_the_policys_step_within_the_rate_set_last():
    # KL_TARGET 0.015: over 0.03 the rate is divided by 1.5, under 0.0075 multiplied by 1.5, never above the rate
    # set last (the file's, or the NaN guard's) nor below a 30th of it
    ppo = PPO((4,), MLP_CONTINUOUS, Hyperparameters(lr=3e-4), device="cpu", seed=0)
    ppo.steer_lr(0.05)
    assert ppo.lr == pytest.approx(2e-4)
    ppo.steer_lr(0.02)  # between the bounds: kept
    assert ppo.lr == pytest.approx(2e-4)
    ppo.steer_lr(0.001)
    ppo.steer_lr(0.001)
    assert ppo.lr == pytest.approx(3e-4) and ppo.lr_ceiling == 3e-4  # back up, and no further
    for _ in range(20):
        ppo.steer_lr(1.0)
    assert ppo.lr == pytest.approx(1e-5)
    ppo.steer_lr(float("nan"))
    assert ppo.lr == pytest.approx(1e-5)
    ppo.lr = 1e-4  # the NaN guard halving, or an edited hyperparameters.json: the new ceiling
    ppo.steer_lr(0.001)
    assert ppo.lr == ppo.lr_ceiling == 1e-4
    ppo.steer_lr(0.05)
    again = PPO((4,), MLP_CONTINUOUS, device="cpu", seed=1)
    again.load_state_dict(ppo.state_dict())
    assert (again.lr, again.lr_ceiling) == (pytest.approx(1e-4 / 1.5), 1e-4)


def test_learn_steers_the_rate_by_its_own_update():
    # a rate far too high moves the policy well past 2 × KL_TARGET in one learn: the next runs at 1/1.5 of it
    ppo = PPO((4,), MLP_CONTINUOUS, Hyperparameters(lr=0.05, num_epochs=10), device="cpu", seed=0)
    obs = np.random.default_rng(0).normal(size=(64, 4)).astype(np.float32)
    ends = np.zeros(64, bool)
    ends[-1] = True
    ro = _rollout(ppo, obs, [], np.zeros(64, bool), ends)
    ro.rewards = -np.sum((ro.actions - 0.5) ** 2, 1).astype(np.float32)
    metrics = ppo.learn(ro)
    assert metrics["losses/approx_kl"] > 0.03 and metrics["charts/learning_rate"] == pytest.approx(0.05)
    assert ppo.lr == pytest.approx(0.05 / 1.5) and ppo.lr_ceiling == 0.05
