"""Soft actor-critic for continuous action spaces, with AWS DeepRacer's settings where they carry over.

From AWS (facts §5, §6; SIM `sagemaker_graph_manager.get_sac_params`): a fixed entropy coefficient
α = sac_alpha (no automatic tuning), γ = discount_factor, Adam with lr and eps 1e-5, Huber or MSE critic
loss per loss_type, minibatches of batch_size from a replay memory, a tanh-squashed Gaussian policy with a
state-dependent log-std clipped to [-20, 2], the mean action for evaluation, and as many gradient steps
per iteration as environment steps were collected (the caller passes that number to `update`).

Where racerlab differs: AWS runs rl_coach's SAC v1 (a state-value network V with a target copy, τ = 1,
copied every num_episodes_between_training environment steps). We use the later, standard form (twin Q
networks with Polyak-averaged targets, τ = 0.005 per gradient step; Haarnoja et al. 2018b), which has one
network fewer and no separate V to tune. As with PPO, `terminated` cuts the bootstrap and a truncated
transition bootstraps from its `next_obs` (pass the final observation, not the reset one).

Actions are in [-1, 1]^2 ([steer, speed]); `ContinuousActions.rescale` maps them to the car's ranges, the
same map AWS applies inside its SAC head.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import torch

from racerlab.agent.common import (
    Obs,
    generator_state,
    make_generator,
    resolve_device,
    restore_generator,
    seeded,
    take,
    to_tensors,
)
from racerlab.agent.networks import MLP_HIDDEN, build_sac_networks
from racerlab.agent.ppo import ADAM_EPS, value_loss
from racerlab.model import Hyperparameters

TAU = 0.005
BUFFER_SIZE = 100_000
STATE_FORMAT = "racerlab.sac/1"


# ---------------------------------------------------------------------------------------------------
# Replay memory
# ---------------------------------------------------------------------------------------------------


class ReplayBuffer:
    """A ring buffer of transitions, numpy, batch axis first; arrays are allocated on the first `add`.

    Observations keep their dtype (uint8 images: 19 kB per camera frame, twice per transition).
    """

    def __init__(self, capacity: int = BUFFER_SIZE):
        self.capacity = int(capacity)
        self.pos = 0
        self.size = 0
        self.data: dict[str, np.ndarray] | None = None

    def __len__(self) -> int:
        return self.size

    def _allocate(self, fields: dict[str, np.ndarray]) -> None:
        self.data = {k: np.zeros((self.capacity, *v.shape[1:]), dtype=v.dtype) for k, v in fields.items()}

    def add(self, obs: Obs, actions, rewards, next_obs: Obs, terminated) -> None:
        """Append B transitions; every argument has the batch axis first."""
        fields = {**_prefixed("obs", obs), **_prefixed("next_obs", next_obs),
                  "actions": np.asarray(actions, dtype=np.float32),
                  "rewards": np.asarray(rewards, dtype=np.float32),
                  "terminated": np.asarray(terminated, dtype=np.float32)}
        if self.data is None:
            self._allocate(fields)
        b = len(fields["rewards"])
        idx = (self.pos + np.arange(b)) % self.capacity
        for k, v in fields.items():
            self.data[k][idx] = v
        self.pos = int((self.pos + b) % self.capacity)
        self.size = min(self.size + b, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        idx = rng.integers(0, self.size, size=batch_size)
        return {k: v[idx] for k, v in self.data.items()}


def _prefixed(prefix: str, obs: Obs) -> dict[str, np.ndarray]:
    if isinstance(obs, Mapping):
        return {f"{prefix}/{k}": np.asarray(v) for k, v in obs.items()}
    return {prefix: np.asarray(obs)}


def _unprefixed(sample: dict[str, np.ndarray], prefix: str) -> Obs:
    if prefix in sample:
        return sample[prefix]
    return {k[len(prefix) + 1:]: v for k, v in sample.items() if k.startswith(prefix + "/")}


# ---------------------------------------------------------------------------------------------------
# Losses (pure)
# ---------------------------------------------------------------------------------------------------


class SACLosses(NamedTuple):
    q_loss: torch.Tensor
    pi_loss: torch.Tensor


def soft_q_target(rewards, terminated, next_q1, next_q2, next_log_probs, gamma: float, alpha: float):
    """y = r + γ (1 − terminated) (min(Q1', Q2') − α log π(a'|s')), all [M]."""
    return rewards + gamma * (1.0 - terminated) * (torch.min(next_q1, next_q2) - alpha * next_log_probs)


def policy_loss(q1_pi, q2_pi, log_probs, alpha: float) -> torch.Tensor:
    """E[α log π(a|s) − min(Q1, Q2)(s, a)] with a ~ π reparameterised."""
    return (alpha * log_probs - torch.min(q1_pi, q2_pi)).mean()


# ---------------------------------------------------------------------------------------------------
# The agent
# ---------------------------------------------------------------------------------------------------


class SAC:
    """SAC for a continuous model: `act`, `observe` transitions, `update(gradient_steps)`. `deadline` (a
    `time.perf_counter()` value, set by the trainer for `--minutes`) ends an update early."""

    deadline: float | None = None

    def __init__(self, obs, metadata, hyperparameters: Hyperparameters | None = None, *,
                 device: str | torch.device = "auto", seed: int = 0, buffer_size: int = BUFFER_SIZE,
                 tau: float = TAU, mlp_hidden=MLP_HIDDEN):
        self.metadata = metadata
        self.hp = hyperparameters or Hyperparameters()
        self.device = resolve_device(device)
        self.tau = tau
        with seeded(seed):
            actor, q1, q2 = build_sac_networks(obs, metadata, mlp_hidden)
            q1_target, q2_target = build_sac_networks(obs, metadata, mlp_hidden)[1:]
        self.actor, self.q1, self.q2 = (m.to(self.device) for m in (actor, q1, q2))
        self.q1_target, self.q2_target = q1_target.to(self.device), q2_target.to(self.device)
        self.q1_target.load_state_dict(self.q1.state_dict())
        self.q2_target.load_state_dict(self.q2.state_dict())
        for p in [*self.q1_target.parameters(), *self.q2_target.parameters()]:
            p.requires_grad_(False)
        self.keys = self.actor.body.keys
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=self.hp.lr, eps=ADAM_EPS)
        q_params = [*self.q1.parameters(), *self.q2.parameters()]
        self.q_optimizer = torch.optim.Adam(q_params, lr=self.hp.lr, eps=ADAM_EPS)
        self.generator = make_generator(seed, self.device)
        self.rng = np.random.default_rng(seed)
        self.buffer = ReplayBuffer(buffer_size)
        self.gradient_steps = 0

    @property
    def alpha(self) -> float:
        return self.hp.sac_alpha

    @property
    def lr(self) -> float:
        return self.actor_optimizer.param_groups[0]["lr"]

    @lr.setter
    def lr(self, value: float) -> None:
        for opt in (self.actor_optimizer, self.q_optimizer):
            for group in opt.param_groups:
                group["lr"] = float(value)

    # -- acting ---------------------------------------------------------------------------------------

    @torch.inference_mode()
    def act(self, obs: Obs, greedy: bool = False) -> np.ndarray:
        """Actions [B, 2] in (-1, 1): sampled for training, tanh(mean) for evaluation."""
        dist = self.actor.distribution(to_tensors(obs, self.keys, self.device))
        actions = dist.mode() if greedy else dist.rsample(self.generator)[0]
        return actions.cpu().numpy()

    def policy(self, obs: Obs) -> np.ndarray:
        """The greedy actions [B, 2] (tanh of the mean), as evaluation drives."""
        return self.act(obs, greedy=True)

    def explore(self, obs: Obs) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """A training rollout's sampled actions; SAC needs nothing else kept per step."""
        return self.act(obs), {}

    def observe(self, obs: Obs, actions, rewards, next_obs: Obs, terminated) -> None:
        """Store B transitions; for a truncated episode `next_obs` is its final observation."""
        self.buffer.add(obs, actions, rewards, next_obs, terminated)

    # -- learning -------------------------------------------------------------------------------------

    def learn(self, rollout) -> dict[str, float]:
        """One iteration: the rollout's transitions go to the replay memory, then one gradient step per
        environment step (AWS). A truncated episode's last transition leads to its final observation."""
        n = rollout.rewards.size
        if n == 0:
            return {}
        nxt = np.minimum(np.arange(n) + 1, n - 1)
        ended = rollout.terminated | rollout.truncated
        nxt[ended] = np.flatnonzero(ended)  # placeholder rows: ignored where terminated, replaced where truncated
        next_obs = take(rollout.obs, nxt)
        rows = np.flatnonzero(rollout.truncated)
        if rows.size:
            if isinstance(next_obs, dict):
                for k in next_obs:
                    next_obs[k][rows] = rollout.final_obs[k]
            else:
                next_obs[rows] = rollout.final_obs
        self.observe(rollout.obs, rollout.actions, rollout.rewards, next_obs, rollout.terminated)
        return self.update(n)

    def update(self, gradient_steps: int = 1) -> dict[str, float]:
        """Gradient steps on minibatches from the replay memory; mean metrics.

        Stops early with `nonfinite = 1.0` if a loss turns non-finite, like `PPO.update`.
        """
        if len(self.buffer) == 0:
            raise ValueError("SAC.update before any transition was observed")
        history, nonfinite = [], False
        for _ in range(gradient_steps):
            losses = self._step(self._sample())
            if losses is None:
                nonfinite = True
                break
            history.append(torch.stack(losses))
            if self.deadline is not None and time.perf_counter() >= self.deadline:
                break
        means = torch.stack(history).mean(0).tolist() if history else [float("nan")] * 2
        return {"losses/q": means[0], "losses/policy": means[1], "charts/alpha": self.alpha,
                "charts/learning_rate": self.lr, "charts/gradient_steps": float(len(history)),
                "charts/buffer_size": float(len(self.buffer)), "nonfinite": float(nonfinite)}

    def _sample(self) -> dict:
        s = self.buffer.sample(self.hp.batch_size, self.rng)
        dev = self.device
        return {"obs": to_tensors(_unprefixed(s, "obs"), self.keys, dev),
                "next_obs": to_tensors(_unprefixed(s, "next_obs"), self.keys, dev),
                **{k: torch.as_tensor(s[k], device=dev) for k in ("actions", "rewards", "terminated")}}

    def _step(self, b: dict) -> SACLosses | None:
        # -- critics: regress both Q nets on the soft Bellman target from the target nets --
        with torch.no_grad():
            next_actions, next_log_probs = self.actor.distribution(b["next_obs"]).rsample(self.generator)
            target = soft_q_target(b["rewards"], b["terminated"], self.q1_target(b["next_obs"], next_actions),
                                   self.q2_target(b["next_obs"], next_actions), next_log_probs,
                                   self.hp.discount_factor, self.alpha)
        q_loss = (value_loss(self.q1(b["obs"], b["actions"]), target, self.hp.loss_type)
                  + value_loss(self.q2(b["obs"], b["actions"]), target, self.hp.loss_type))
        # -- actor: maximise min-Q minus α log π with reparameterised actions --
        actions, log_probs = self.actor.distribution(b["obs"]).rsample(self.generator)
        pi_loss = policy_loss(self.q1(b["obs"], actions), self.q2(b["obs"], actions), log_probs, self.alpha)
        if not (torch.isfinite(q_loss) and torch.isfinite(pi_loss)):
            return None
        self.q_optimizer.zero_grad(set_to_none=True)
        self.actor_optimizer.zero_grad(set_to_none=True)
        # The actor loss also reaches the Q nets' weights; those gradients are discarded, the Q step
        # uses the critic loss alone.
        pi_loss.backward()
        self.actor_optimizer.step()
        self.q_optimizer.zero_grad(set_to_none=True)
        q_loss.backward()
        self.q_optimizer.step()
        self._soft_update()
        self.gradient_steps += 1
        return SACLosses(q_loss.detach(), pi_loss.detach())

    @torch.no_grad()
    def _soft_update(self) -> None:
        for net, target in ((self.q1, self.q1_target), (self.q2, self.q2_target)):
            t_params, params = list(target.parameters()), list(net.parameters())
            torch._foreach_lerp_(t_params, params, self.tau)

    # -- checkpoints ----------------------------------------------------------------------------------

    def _modules(self) -> dict[str, torch.nn.Module]:
        return {"actor": self.actor, "q1": self.q1, "q2": self.q2, "q1_target": self.q1_target,
                "q2_target": self.q2_target}

    def networks(self) -> tuple[torch.nn.Module, ...]:
        return tuple(self._modules().values())

    def finite(self) -> bool:
        params = [p for m in self._modules().values() for p in m.parameters()]
        return bool(torch.stack([torch.isfinite(p).all() for p in params]).all())

    def state_dict(self) -> dict:
        """Weights, optimizers, lr and random state, as a deep-copied snapshot (see `PPO.state_dict`).

        The replay memory is not included (it can be gigabytes); a resumed SAC refills it.
        """
        state = {"format": STATE_FORMAT, **{k: m.state_dict() for k, m in self._modules().items()},
                 "actor_optimizer": self.actor_optimizer.state_dict(),
                 "q_optimizer": self.q_optimizer.state_dict(), "lr": self.lr,
                 "gradient_steps": self.gradient_steps, "generator": generator_state(self.generator),
                 "rng": self.rng.bit_generator.state}
        return copy.deepcopy(state)

    def load_state_dict(self, state: dict) -> None:
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"not a SAC state (format {state.get('format')!r}, expected {STATE_FORMAT!r})")
        for k, m in self._modules().items():
            m.load_state_dict(state[k])
        self.actor_optimizer.load_state_dict(copy.deepcopy(state["actor_optimizer"]))
        self.q_optimizer.load_state_dict(copy.deepcopy(state["q_optimizer"]))
        self.lr = state["lr"]
        self.gradient_steps = int(state["gradient_steps"])
        restore_generator(self.generator, state.get("generator"))
        if "rng" in state:
            self.rng.bit_generator.state = state["rng"]
