"""Clipped PPO as AWS DeepRacer configures it (facts §6), in one file, top to bottom.

Which update a model runs: one loss, three implementations that the tests hold equal step by step.
- Dense-layer networks on one vector input (the default `features` model, lidar) on the CPU run
  `agent/mlp_kernel.py`: the minibatch loop, gradients written out by hand and Adam, compiled with numba
  (`MLPUpdater`, engine "numba", ~8x faster than the torch update on 64-wide layers).
- `fast_update="numpy"` runs the same steps in NumPy (`agent/mlp_update.py`), the reference the kernel
  was written from.
- Every other network (cameras, several inputs, a GPU, or `fast_update=False`) runs `PPO.update` below:
  torch autograd on `ppo_losses`, the readable version of the loss the two above implement.

What AWS does, and so what this does:
- separate policy and value networks (`networks.py`); Adam with lr, eps 1e-5, betas (0.9, 0.999);
  no gradient clipping, no value clipping, no L2;
- GAE with λ = 0.95 and γ = discount_factor, value targets = advantage + V(s), computed once per
  iteration with the networks that collected the data; advantages standardised over the whole iteration;
- loss = clipped surrogate (ε = 0.2) + value loss (Huber δ=1 or MSE per loss_type, weight 1)
  − beta_entropy · entropy;
- num_epochs passes; each shuffles and runs int(N / batch_size) minibatches, the remainder dropped; when
  the iteration has fewer than batch_size steps, the minibatch is the largest power of 2 ≤ N;
- strictly on-policy: the caller throws the batch away after `update`.

Where racerlab differs from AWS, on purpose: AWS bootstraps 0 at every episode end. We keep
*termination* (crash, off-track, reversed, ...: bootstrap 0, exactly AWS's rule) apart from
*truncation* (a step limit, a completed lap, or an episode cut by the end of a rollout: bootstrap with
V of the observation after the last step) — a timeout is not a wall, and neither is the finish line:
no observation tells how near it is, and a 0 there made arriving sooner look worse (issue 17,
`racerlab.train.rollout`). Two more (issue 32, docs/learner.md): the value net learns the returns over a
running scale (`RETURN_SCALE_WEIGHT`), and the learning rate is steered by each update's approx KL
(`KL_TARGET`), within hyperparameters.json's lr.

How the training loop feeds it (the batch representation):
1. `actions, log_probs, values = ppo.act(obs)` for each step of B cars (numpy in, numpy out).
2. Keep whole episodes. Either as [T, B] arrays (time-major, one column per car) or as *flat* [N]
   arrays: completed episodes concatenated one after another, each in time order. In both, a step where
   the episode ended has `terminated` or `truncated` True; `next_values[t]` is V(obs after step t):
   values[t + 1] inside an episode, `ppo.value(final_obs)` at a truncation, anything (ignored) at a
   termination. `episode_next_values` builds it for the flat form.
3. `batch = make_batch(obs, actions, log_probs, values, rewards, next_values, terminated, truncated, gamma)`
   computes GAE and flattens [T, B] to [N].
4. `metrics = ppo.update(batch)`.
"""

from __future__ import annotations

import contextlib
import copy
import math
import time
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from numba import njit

from racerlab.agent.common import (
    Obs,
    ThreadChooser,
    batch_size_of,
    generator_state,
    learner_threads,
    make_generator,
    resolve_device,
    restore_generator,
    seeded,
    to_tensors,
)
from racerlab.agent.distributions import PPO_LOG_STD_MAX, PPO_LOG_STD_MIN, epsilon_greedy, epsilon_schedule
from racerlab.agent.mlp_update import MLPUpdater
from racerlab.agent.networks import PPO_MLP_HIDDEN, build_ppo_networks
from racerlab.errors import ConfigError
from racerlab.model import Hyperparameters

CLIP_EPSILON = 0.2
GAE_LAMBDA = 0.95
ADAM_EPS = 1e-5
VALUE_LOSS_WEIGHT = 1.0
# The value network learns returns divided by `PPO.return_scale`, a running RMS of the discounted returns
# (each iteration's RMS blended in with this weight): a lap of ~90 steps paid ~0.7 a step has returns near 50,
# where Huber's δ = 1 turns the value loss into |error| and the value net crawled (explained variance ~0.2
# after 50 iterations, docs/learner.md). Scaled, the errors sit inside δ and any reward's scale learns alike.
RETURN_SCALE_WEIGHT = 0.1
# The learning rate follows the policy's step: after an update whose approx KL passed 2 × KL_TARGET it is divided
# by LR_STEP, after one under KL_TARGET / 2 multiplied by it, never above the rate set last (hyperparameters.json's
# lr, or what the NaN guard lowered it to) nor below that / LR_RANGE. As the policy's std shrinks, a fixed rate's
# steps grow in KL: a 30-minute run's median went 0.01 -> 0.045 nats, clip fraction 0.13 -> 0.33, with spikes to
# 59 nats, and its evaluation laps drifted from 92 to 95 steps (docs/learner.md). AWS's rate is fixed.
KL_TARGET = 0.015
LR_STEP = 1.5
LR_RANGE = 30.0
STATE_FORMAT = "racerlab.ppo/1"


# ---------------------------------------------------------------------------------------------------
# Generalised advantage estimation
# ---------------------------------------------------------------------------------------------------


def compute_gae(rewards, values, next_values, terminated, truncated, gamma: float,
                lam: float = GAE_LAMBDA) -> tuple[np.ndarray, np.ndarray]:
    """Advantages and value targets, arrays [T, B] (or flat [N], see the module docstring).

    δ_t = r_t + γ·(0 if terminated_t else next_values_t) − values_t
    A_t = δ_t + γλ·A_{t+1}, the recursion cut where the episode ended (terminated or truncated).
    A step at the end of the arrays that did not end its episode bootstraps from next_values, like a
    truncation. Returns (advantages, returns = advantages + values), float32, same shape as rewards.
    """
    rewards = np.asarray(rewards, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    terminated = np.asarray(terminated, dtype=bool)
    ended = terminated | np.asarray(truncated, dtype=bool)
    advantages = np.zeros_like(rewards)
    columns = (-1, 1) if rewards.ndim == 1 else rewards.shape  # flat [N] as one column [N, 1]
    _gae_recursion(*(np.ascontiguousarray(a).reshape(columns) for a in (
        rewards, values, np.asarray(next_values, dtype=np.float64), terminated, ended, advantages)),
        float(gamma), float(lam))
    return advantages.astype(np.float32), (advantages + values).astype(np.float32)


@njit(cache=True)
def _gae_recursion(rewards, values, next_values, terminated, ended, out, gamma, lam):
    """The backward recursion of `compute_gae` on [T, B] float64 arrays, into `out` (a Python loop over
    the ~7 000 steps of an iteration took 44 ms, as long as a quarter of the update)."""
    for b in range(rewards.shape[1]):
        last = 0.0
        for t in range(rewards.shape[0] - 1, -1, -1):
            delta = rewards[t, b] + gamma * (0.0 if terminated[t, b] else next_values[t, b]) - values[t, b]
            last = delta + gamma * lam * (0.0 if ended[t, b] else last)
            out[t, b] = last


def episode_next_values(values, ended, end_values) -> np.ndarray:
    """next_values [N] for flat concatenated episodes.

    values [N]: V(s_t) from `act`; ended [N] bool: last step of each episode (terminated or truncated);
    end_values [number of episodes]: V(final observation) of each episode in order (use 0 for
    terminated episodes; it is ignored). The flat arrays must end with a completed episode.
    """
    values = np.asarray(values, dtype=np.float32)
    ended = np.asarray(ended, dtype=bool)
    if len(ended) and not ended[-1]:
        raise ValueError("flat episodes must end with a completed episode (ended[-1] is False)")
    next_values = np.empty_like(values)
    next_values[:-1] = values[1:]
    next_values[ended] = np.asarray(end_values, dtype=np.float32)
    return next_values


class PPOBatch(NamedTuple):
    """One iteration's data, flat [N] (numpy). Made by `make_batch`; consumed by `PPO.update`."""

    obs: Obs  # [N, ...] array or {input: [N, ...]}
    actions: np.ndarray  # [N] int64 indices, or [N, 2] float32 unclipped continuous actions
    log_probs: np.ndarray  # [N] log π_old(a|s) from act()
    values: np.ndarray  # [N] V_old(s) from act()
    advantages: np.ndarray  # [N] raw GAE advantages (update() standardises them)
    returns: np.ndarray  # [N] value targets


def _flatten(x: Obs, n: int):
    if isinstance(x, Mapping):
        return {k: _flatten(v, n) for k, v in x.items()}
    x = np.asarray(x)
    return x.reshape(n, *x.shape[2:])


def make_batch(obs: Obs, actions, log_probs, values, rewards, next_values, terminated, truncated,
               gamma: float, lam: float = GAE_LAMBDA) -> PPOBatch:
    """GAE + flattening: inputs [T, B, ...] (time-major) or flat [N, ...] whole episodes."""
    advantages, returns = compute_gae(rewards, values, next_values, terminated, truncated, gamma, lam)
    if advantages.ndim == 2:
        n = advantages.size
        obs, actions, log_probs, values = (_flatten(x, n) for x in (obs, actions, log_probs, values))
        advantages, returns = advantages.reshape(n), returns.reshape(n)
    return PPOBatch(obs, np.asarray(actions), np.asarray(log_probs, dtype=np.float32),
                    np.asarray(values, dtype=np.float32), advantages, returns)


# ---------------------------------------------------------------------------------------------------
# Losses (pure)
# ---------------------------------------------------------------------------------------------------


class PPOLosses(NamedTuple):
    loss: torch.Tensor  # what is minimised
    pg_loss: torch.Tensor
    v_loss: torch.Tensor
    entropy: torch.Tensor
    approx_kl: torch.Tensor  # E[(r − 1) − log r], Schulman's low-variance estimator of KL(old ‖ new)
    clipfrac: torch.Tensor  # share of samples with |r − 1| > ε


def value_loss(predicted: torch.Tensor, target: torch.Tensor, loss_type: str) -> torch.Tensor:
    """Huber (δ = 1, TF's default) or mean squared error, averaged; AWS's `replace_mse_with_huber_loss`."""
    if loss_type == "huber":
        return F.huber_loss(predicted, target, delta=1.0)
    return F.mse_loss(predicted, target)


def ppo_losses(new_log_probs, old_log_probs, advantages, new_values, returns, entropy, *,
               clip: float = CLIP_EPSILON, loss_type: str = "huber", beta_entropy: float = 0.01) -> PPOLosses:
    """The clipped-PPO loss on a minibatch; every input is [M]."""
    logratio = new_log_probs - old_log_probs
    ratio = logratio.exp()
    pg_loss1 = -advantages * ratio
    pg_loss2 = -advantages * ratio.clamp(1.0 - clip, 1.0 + clip)
    pg_loss = torch.max(pg_loss1, pg_loss2).mean()
    v_loss = value_loss(new_values, returns, loss_type)
    entropy = entropy.mean()
    loss = pg_loss + VALUE_LOSS_WEIGHT * v_loss - beta_entropy * entropy
    with torch.no_grad():
        approx_kl = ((ratio - 1.0) - logratio).mean()
        clipfrac = ((ratio - 1.0).abs() > clip).float().mean()
    return PPOLosses(loss, pg_loss, v_loss, entropy, approx_kl, clipfrac)


def minibatch_size(n: int, batch_size: int) -> int:
    """batch_size, or the largest power of 2 ≤ n when the iteration is smaller (AWS training_worker)."""
    if n >= batch_size:
        return batch_size
    return 1 << (n.bit_length() - 1) if n > 0 else 0


def explained_variance(predicted: np.ndarray, target: np.ndarray) -> float:
    """1 − Var(target − predicted) / Var(target); 0.0 when the targets do not vary."""
    var = float(np.var(target))
    return 0.0 if var == 0.0 else float(1.0 - np.var(target - predicted) / var)


# ---------------------------------------------------------------------------------------------------
# The agent
# ---------------------------------------------------------------------------------------------------


class PPO:
    """Clipped PPO for a model's metadata (action space, network) and hyperparameters.

    `obs` is the observation space or shapes (see `networks.observation_shapes`). `device` "auto" is
    CUDA when present, else CPU. `seed` fixes the initial weights, sampling and shuffling.
    `fast_update`: networks of dense layers on one vector input (features, lidar) update on the CPU
    through `mlp_update` (the same loss and Adam step, without autograd's overhead): True or "numba" in one
    compiled function, "numpy" with NumPy operations; False keeps torch's.
    `deadline` (a `time.perf_counter()` value, set by the trainer for `--minutes`) ends an update early,
    after the minibatch in progress.
    """

    deadline: float | None = None
    # the torch update picks 1 thread or torch's count, whichever runs faster now (`common.ThreadChooser`);
    # the trainer turns this off when training.toml's run.threads fixes the count
    adapt_threads: bool = True
    threads: int = 0  # torch CPU threads for the torch update (`common.learner_threads`; 0 = auto)

    def __init__(self, obs, metadata, hyperparameters: Hyperparameters | None = None, *,
                 device: str | torch.device = "auto", seed: int = 0, mlp_hidden=PPO_MLP_HIDDEN,
                 fast_update: bool | str = True):
        self.metadata = metadata
        self.hp = hyperparameters or Hyperparameters()
        self.discrete = metadata.action_space_type == "discrete"
        if self.discrete and self.hp.exploration_type not in ("categorical", "e-greedy"):
            raise ConfigError(f"{self.hp.source}: exploration_type must be \"categorical\" or \"e-greedy\" "
                              f"for discrete actions, got {self.hp.exploration_type!r}")
        self.device = resolve_device(device)
        with seeded(seed):
            policy, value = build_ppo_networks(obs, metadata, mlp_hidden)
        self.policy_net, self.value_net = policy.to(self.device), value.to(self.device)
        self.keys = self.policy_net.body.keys
        params = [*self.policy_net.parameters(), *self.value_net.parameters()]
        if any(isinstance(m, torch.nn.Conv2d) for m in self.policy_net.modules()):
            # oneDNN's convolutions run ~8 % faster on channels-last weights (the images arrive NHWC)
            self.policy_net.to(memory_format=torch.channels_last)
            self.value_net.to(memory_format=torch.channels_last)
        # fused: one kernel for all weights (the same update as torch's per-tensor Adam)
        self.optimizer = torch.optim.Adam(params, lr=self.hp.lr, betas=(0.9, 0.999), eps=ADAM_EPS, fused=True)
        self.lr_ceiling = float(self.hp.lr)  # the rate `steer_lr` never exceeds
        self.generator = make_generator(seed, self.device)
        # small vector networks on the CPU: the same update compiled (or in NumPy), without autograd's overhead
        covered = fast_update and MLPUpdater.covers(self.policy_net, self.value_net, self.device)
        engine = "numba" if fast_update is True else fast_update
        self._mlp = MLPUpdater(self.policy_net, self.value_net, self.optimizer, discrete=self.discrete,
                               engine=engine) if covered else None
        self.env_steps = 0  # car-steps acted while exploring: the ε-greedy schedule's clock
        self.return_scale: float | None = None  # the value net's unit in reward (RETURN_SCALE_WEIGHT); None: not yet
        self._convolutional = any(isinstance(m, torch.nn.Conv2d) for m in self.policy_net.modules())
        self._inference: dict[str, ThreadChooser] = {}  # thread choice of act and policy, by method

    # -- settings -------------------------------------------------------------------------------------

    @property
    def lr(self) -> float:
        return self.optimizer.param_groups[0]["lr"]

    @lr.setter
    def lr(self, value: float) -> None:
        """Set the rate, and the ceiling `steer_lr` keeps under (the NaN guard, an edited hyperparameters.json)."""
        self._set_lr(value)
        self.lr_ceiling = float(value)

    def _set_lr(self, value: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = float(value)

    def steer_lr(self, approx_kl: float) -> None:
        """After an update: the learning rate toward a step of KL_TARGET (LR_STEP, LR_RANGE)."""
        if not math.isfinite(approx_kl):
            return
        if approx_kl > 2 * KL_TARGET:
            self._set_lr(max(self.lr / LR_STEP, self.lr_ceiling / LR_RANGE))
        elif approx_kl < KL_TARGET / 2:
            self._set_lr(min(self.lr * LR_STEP, self.lr_ceiling))

    @property
    def epsilon(self) -> float:
        """Current ε of the e-greedy schedule (0 with categorical exploration)."""
        if self.hp.exploration_type != "e-greedy":
            return 0.0
        return epsilon_schedule(self.env_steps, self.hp.e_greedy_value, self.hp.epsilon_steps)

    # -- acting ---------------------------------------------------------------------------------------

    @contextlib.contextmanager
    def _threads(self, method: str):
        """A convolutional network's inference on the CPU runs on 1 thread or torch's count, whichever is
        faster now (as its update does; `common.ThreadChooser`, one per calling method), and gives the
        count back after each call. Anything else runs as it is."""
        n = torch.get_num_threads()
        if not (self._convolutional and self.adapt_threads and self.device.type == "cpu" and n > 1):
            yield
            return
        chooser = self._inference.get(method)
        if chooser is None or chooser.threads != n:
            chooser = self._inference[method] = ThreadChooser(n)
        try:
            with chooser:
                yield
        finally:
            chooser.restore()

    @torch.inference_mode()
    def act(self, obs: Obs, greedy: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(actions [B], log_probs [B], values [B]) for a batch of observations.

        Training (greedy=False) samples: softmax or ε-greedy for discrete actions, N(mean, std) for
        continuous ones (unclipped). Evaluation (greedy=True) takes the argmax or the mean, as AWS.
        log_probs are the policy's own, even for an ε-greedy action: AWS's ratio uses the policy.
        """
        with self._threads("act"):
            return self._act(obs, greedy)

    def _act(self, obs: Obs, greedy: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = to_tensors(obs, self.keys, self.device)
        dist = self.policy_net.distribution(x)
        if greedy:
            actions = dist.mode()
        elif self.discrete and self.hp.exploration_type == "e-greedy":
            actions = epsilon_greedy(dist, self.epsilon, self.generator)
        else:
            actions = dist.sample(self.generator)
        log_probs = dist.log_prob(actions)
        values = self.value_net(x) * (self.return_scale or 1.0)
        if not greedy:
            self.env_steps += batch_size_of(x)
        return actions.cpu().numpy(), log_probs.cpu().numpy(), values.cpu().numpy()

    @torch.inference_mode()
    def value(self, obs: Obs) -> np.ndarray:
        """V(s) [B] in the reward's units, e.g. of the final observation of a truncated episode."""
        return self.value_net(to_tensors(obs, self.keys, self.device)).cpu().numpy() * (self.return_scale or 1.0)

    def policy(self, obs: Obs) -> np.ndarray:
        """The greedy actions [B] (argmax or mean), as evaluation drives. A vector network computes them in
        NumPy (`MLPUpdater.greedy`: ~9 µs for 5 cars, where the torch modules' dispatch took ~40 µs)."""
        if self._mlp is not None:
            return self._mlp.greedy(obs[self.keys[0]] if isinstance(obs, Mapping) else obs)
        with torch.inference_mode(), self._threads("policy"):
            return self.policy_net.distribution(to_tensors(obs, self.keys, self.device)).mode().cpu().numpy()

    def explore(self, obs: Obs) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """A training rollout's actions and what `learn` needs back for each step (log-probs, values)."""
        actions, log_probs, values = self.act(obs)
        return actions, {"log_probs": log_probs, "values": values}

    # -- learning -------------------------------------------------------------------------------------

    def learn(self, rollout) -> dict[str, float]:
        """One iteration's update from a training rollout (`racerlab.train.rollout.Rollout`: whole episodes,
        flat, with `explore`'s log-probs and values); a truncated episode bootstraps from V of its final
        observation. Rewards and values are divided by `return_scale` (updated first, `RETURN_SCALE_WEIGHT`), so
        the value net learns returns near 1 whatever the reward's scale. Returns `update`'s metrics ({} for an
        empty rollout) and the learner's diagnostics (`learner/...`, in the reward's units)."""
        if rollout.rewards.size == 0:
            return {}
        values = np.asarray(rollout.record["values"], dtype=np.float32)
        ended = rollout.terminated | rollout.truncated
        end_values = np.zeros(int(ended.sum()), dtype=np.float32)
        cut = rollout.truncated[ended]
        if cut.any():
            end_values[cut] = self.value(rollout.final_obs)
        next_values = episode_next_values(values, ended, end_values)
        first = self.return_scale is None  # then the net's outputs are taken as already in the new unit
        unit = np.float32(self._update_return_scale(rollout))
        to_unit = np.float32(1.0) if first else unit
        batch = make_batch(rollout.obs, rollout.actions, rollout.record["log_probs"], values / to_unit,
                           np.asarray(rollout.rewards, dtype=np.float32) / unit, next_values / to_unit,
                           rollout.terminated, rollout.truncated, self.hp.discount_factor)
        diagnostics = self._diagnostics(batch)
        metrics = self.update(batch)
        self.steer_lr(metrics.get("losses/approx_kl", math.nan))  # none from a non-finite update: kept
        return {**metrics, **diagnostics}

    def _update_return_scale(self, rollout) -> float:
        """Blend this rollout's RMS discounted return (to each episode's end, γ = discount_factor) into
        `return_scale` with weight RETURN_SCALE_WEIGHT (the first rollout sets it) and return it."""
        zeros = np.zeros(rollout.rewards.shape, dtype=np.float32)
        returns, _ = compute_gae(rollout.rewards, zeros, zeros, rollout.terminated, rollout.truncated,
                                 self.hp.discount_factor, lam=1.0)
        rms = float(np.sqrt(np.mean(np.square(returns, dtype=np.float64))))
        if math.isfinite(rms) and rms > 0:
            old = self.return_scale
            self.return_scale = rms if old is None else old + RETURN_SCALE_WEIGHT * (rms - old)
        return self.return_scale or 1.0

    def _diagnostics(self, batch: PPOBatch) -> dict[str, float]:
        """What the plateau study reads (docs/learner.md): the value error before the update and the raw
        advantages' spread (reward units), the return scale, and the exploring actions' spread (continuous:
        the policy's std per action dimension, in [-1, 1] action units)."""
        unit = self.return_scale or 1.0
        out = {"learner/return_scale": unit,
               "learner/value_rmse": unit * float(np.sqrt(np.mean(np.square(batch.returns - batch.values)))),
               "learner/advantage_std": unit * float(np.std(batch.advantages))}
        if not self.discrete:
            std = self.policy_net.log_std.detach().clamp(PPO_LOG_STD_MIN, PPO_LOG_STD_MAX).exp().cpu().numpy()
            out.update({f"learner/action_std_{i}": float(v) for i, v in enumerate(std)})
        return out

    def update(self, batch: PPOBatch) -> dict[str, float]:
        """num_epochs passes of minibatch Adam over one iteration's batch; returns mean metrics.

        If a loss turns non-finite, the update stops before applying that step and the metrics carry
        `nonfinite = 1.0`; the caller's NaN guard decides what to do (roll back, lower the lr).
        """
        n = len(batch.advantages)
        if n == 0:
            raise ValueError("PPO.update got an empty batch")
        mb = minibatch_size(n, self.hp.batch_size)
        if self._mlp is not None:
            history, nonfinite = self._update_mlp(batch, n, mb)
        else:
            history, nonfinite = self._update_torch(batch, n, mb)
        return self._metrics(history, batch, mb, nonfinite)

    def _minibatches(self, n: int, mb: int):
        """num_epochs shuffles of range(n), each cut into int(n / mb) index blocks (the rest dropped). Past
        `deadline`, no further block is given: the update ends after the minibatch in progress."""
        first = True
        for _epoch in range(self.hp.num_epochs):
            perm = torch.randperm(n, generator=self.generator, device=self.generator.device)
            for start in range(0, (n // mb) * mb, mb):
                if not first and self.deadline is not None and time.perf_counter() >= self.deadline:
                    return
                first = False
                yield perm[start:start + mb]

    def _blocks(self, n: int, mb: int, rows: int = 16):
        """`_minibatches` for `mlp_update`: the same shuffles, as int64 arrays of up to `rows` minibatches
        [rows, mb]. Past `deadline`, no further block is given, and a first block is cut to one minibatch."""
        first = True
        for _epoch in range(self.hp.num_epochs):
            perm = torch.randperm(n, generator=self.generator, device=self.generator.device)
            epoch = perm[:(n // mb) * mb].reshape(-1, mb).cpu().numpy()
            for start in range(0, len(epoch), rows):
                past = self.deadline is not None and time.perf_counter() >= self.deadline
                if past and not first:
                    return
                yield epoch[start:start + (1 if past else rows)]
                if past:
                    return
                first = False

    @staticmethod
    def _standardised(advantages: np.ndarray) -> np.ndarray:
        # AWS standardises over the whole iteration, once, before the epochs (population std, as numpy).
        a = np.asarray(advantages, dtype=np.float32)
        return ((a - a.mean()) / (a.std() + np.float32(1e-8))).astype(np.float32)

    def _update_torch(self, batch: PPOBatch, n: int, mb: int):
        dev = self.device
        given = torch.get_num_threads()  # the caller's count, given back at the end
        if dev.type == "cpu":  # set again each time: numba's OpenMP launch resets the count torch shares
            torch.set_num_threads(learner_threads(self.networks(), self.threads))
        obs = to_tensors(batch.obs, self.keys, dev)
        action_dtype = torch.int64 if self.discrete else torch.float32
        actions = torch.as_tensor(batch.actions, dtype=action_dtype, device=dev)
        old_log_probs = torch.as_tensor(batch.log_probs, dtype=torch.float32, device=dev)
        returns = torch.as_tensor(batch.returns, dtype=torch.float32, device=dev)
        advantages = torch.as_tensor(self._standardised(batch.advantages), device=dev)
        history: list[torch.Tensor] = []
        threads = ThreadChooser(torch.get_num_threads() if self.adapt_threads and dev.type == "cpu" else 1)
        try:
            for idx in self._minibatches(n, mb):
                with threads:
                    losses = self._minibatch_losses(obs, idx, actions, old_log_probs, advantages, returns)
                    if not torch.isfinite(losses.loss):
                        return history, True
                    self.optimizer.zero_grad(set_to_none=True)
                    losses.loss.backward()
                    self.optimizer.step()
                    history.append(torch.stack([x.detach() for x in losses[1:]]))
        finally:
            threads.restore()
            torch.set_num_threads(given)
        return [h.cpu().numpy() for h in history], False

    def _update_mlp(self, batch: PPOBatch, n: int, mb: int):
        obs = batch.obs[self.keys[0]] if isinstance(batch.obs, Mapping) else batch.obs
        x = np.ascontiguousarray(obs, dtype=np.float32).reshape(n, -1)
        actions = np.asarray(batch.actions, dtype=np.int64 if self.discrete else np.float32)
        return self._mlp.run(x, actions, np.asarray(batch.log_probs, dtype=np.float32),
                             self._standardised(batch.advantages), np.asarray(batch.returns, dtype=np.float32),
                             self._blocks(n, mb), clip=CLIP_EPSILON, beta=self.hp.beta_entropy,
                             loss_type=self.hp.loss_type)

    def _minibatch_losses(self, obs, idx, actions, old_log_probs, advantages, returns) -> PPOLosses:
        mb_obs = {k: v[idx] for k, v in obs.items()}
        dist = self.policy_net.distribution(mb_obs)
        new_log_probs = dist.log_prob(actions[idx])
        new_values = self.value_net(mb_obs)
        return ppo_losses(new_log_probs, old_log_probs[idx], advantages[idx], new_values, returns[idx],
                          dist.entropy(), clip=CLIP_EPSILON, loss_type=self.hp.loss_type,
                          beta_entropy=self.hp.beta_entropy)

    def _metrics(self, history, batch: PPOBatch, mb: int, nonfinite: bool) -> dict[str, float]:
        means = np.mean(history, axis=0).tolist() if history else [float("nan")] * 5
        pg_loss, v_loss, entropy, approx_kl, clipfrac = means
        return {
            "losses/policy": pg_loss,
            "losses/value": v_loss,
            "losses/entropy": entropy,
            "losses/approx_kl": approx_kl,
            "losses/clipfrac": clipfrac,
            "losses/explained_variance": explained_variance(batch.values, batch.returns),
            "charts/learning_rate": self.lr,
            "charts/minibatch_size": float(mb),
            "charts/gradient_steps": float(len(history)),
            "nonfinite": float(nonfinite),
        }

    # -- checkpoints ----------------------------------------------------------------------------------

    @staticmethod
    def _check_shapes(saved: dict, net: torch.nn.Module) -> None:
        """A checkpoint from networks of other widths (features models saved before PPO_MLP_HIDDEN became 64)
        fails with the widths named, not with PyTorch's list of size mismatches."""
        own = net.state_dict()
        for key, value in saved.items():
            if key in own and tuple(value.shape) != tuple(own[key].shape):
                raise ConfigError(f"checkpoint: layer {key} has shape {tuple(value.shape)}, this network's is "
                                  f"{tuple(own[key].shape)}; it was saved by networks of other widths (before "
                                  f"racerlab's features MLP became {PPO_MLP_HIDDEN}): train that model anew")

    def networks(self) -> tuple[torch.nn.Module, ...]:
        return self.policy_net, self.value_net

    def finite(self) -> bool:
        """True when every weight of both networks is finite."""
        params = [*self.policy_net.parameters(), *self.value_net.parameters()]
        return bool(torch.stack([torch.isfinite(p).all() for p in params]).all())

    def state_dict(self) -> dict:
        """Everything to resume exactly: weights, optimizer, lr, ε clock and the random generator.

        A snapshot (deep copy): training on does not change it, so it can serve as the NaN guard's
        last good state in memory. (PyTorch's own state dicts share storage with the live tensors.)
        """
        return copy.deepcopy({"format": STATE_FORMAT, "policy": self.policy_net.state_dict(),
                "value": self.value_net.state_dict(), "optimizer": self.optimizer.state_dict(),
                "lr": self.lr, "env_steps": self.env_steps, "generator": generator_state(self.generator),
                "return_scale": self.return_scale, "lr_ceiling": self.lr_ceiling})

    def load_state_dict(self, state: dict) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"not a PPO state (format {state.get('format')!r}, expected {STATE_FORMAT!r})")
        self._check_shapes(state["policy"], self.policy_net)
        self.policy_net.load_state_dict(state["policy"])
        self.value_net.load_state_dict(state["value"])
        # Optimizer.load_state_dict keeps the given tensors; copy them so the caller's dict stays apart.
        self.optimizer.load_state_dict(copy.deepcopy(state["optimizer"]))
        self.lr = state["lr"]
        self.lr_ceiling = float(state.get("lr_ceiling", state["lr"]))
        self.env_steps = int(state["env_steps"])
        self.return_scale = state.get("return_scale")  # None in states saved before it: set by the next learn
        restore_generator(self.generator, state.get("generator"))
