"""Action distributions, as AWS DeepRacer's rl_coach heads define them (facts §4, §5).

- `Categorical`: discrete actions; softmax probabilities floored at 1e-8 (the PPO head's floor), so a
  log-probability is never -inf and the PPO ratio stays finite. The floored vector is used as is
  (not renormalised) for log-probabilities and entropy, as AWS does; sampling normalises implicitly.
- `epsilon_schedule` / `epsilon_greedy`: the `exploration_type = "e-greedy"` alternative: ε decays
  linearly from 1.0 to `e_greedy_value` over `epsilon_steps` environment steps; with probability ε a
  uniform random action, else the argmax of the policy (rl_coach `EGreedy`).
- `DiagGaussian`: continuous PPO; an unbounded mean and a state-independent log-std (a parameter
  initialised to 0, clipped to [-20, 3]). The *unclipped* sample is what the agent returns and what the
  PPO ratio uses; the environment clips to [-1, 1] before rescaling (`ContinuousActions.rescale`).
- `TanhGaussian`: SAC; state-dependent log-std clipped to [-20, 2], tanh squashing with the log-det
  correction, reparameterised samples.

Shapes: B is the batch, N the number of discrete actions, D the action dimension (2: steer, speed).
All functions take an optional `torch.Generator` so that a seeded agent is reproducible.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

PROB_FLOOR = 1e-8
PPO_LOG_STD_MIN, PPO_LOG_STD_MAX = -20.0, 3.0
SAC_LOG_STD_MIN, SAC_LOG_STD_MAX = -20.0, 2.0
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


class Categorical:
    """Discrete distribution from logits [B, N] with probabilities floored at 1e-8."""

    def __init__(self, logits: torch.Tensor):
        self.probs = F.softmax(logits, dim=-1).clamp_min(PROB_FLOOR)  # [B, N]

    def log_prob(self, actions: torch.Tensor) -> torch.Tensor:
        """[B] integer actions -> [B] log-probabilities."""
        return self.probs.gather(-1, actions.long().unsqueeze(-1)).squeeze(-1).log()

    def entropy(self) -> torch.Tensor:
        return -(self.probs * self.probs.log()).sum(-1)  # [B]

    def sample(self, generator: torch.Generator | None = None) -> torch.Tensor:
        return torch.multinomial(self.probs, 1, generator=generator).squeeze(-1)  # [B]

    def mode(self) -> torch.Tensor:
        return self.probs.argmax(-1)  # [B]


def epsilon_schedule(step: int, final: float, steps: int, initial: float = 1.0) -> float:
    """ε after `step` environment steps: linear from `initial` to `final` over `steps`, then `final`."""
    if steps <= 0:
        return float(final)
    frac = min(max(step, 0), steps) / steps
    return float(initial + (final - initial) * frac)


def epsilon_greedy(dist: Categorical, epsilon: float,
                   generator: torch.Generator | None = None) -> torch.Tensor:
    """[B] actions: uniform with probability ε, else the most probable action."""
    probs = dist.probs
    b, n = probs.shape
    explore = torch.rand(b, generator=generator, device=probs.device) < epsilon
    uniform = torch.randint(0, n, (b,), generator=generator, device=probs.device)
    return torch.where(explore, uniform, dist.mode())


class DiagGaussian:
    """Gaussian with mean [B, D] and log-std [D] or [B, D] clipped to [-20, 3] (PPO head)."""

    def __init__(self, mean: torch.Tensor, log_std: torch.Tensor,
                 log_std_min: float = PPO_LOG_STD_MIN, log_std_max: float = PPO_LOG_STD_MAX):
        self.mean = mean
        self.log_std = log_std.clamp(log_std_min, log_std_max).expand_as(mean)
        self.std = self.log_std.exp()

    def log_prob(self, actions: torch.Tensor) -> torch.Tensor:
        """[B, D] actions -> [B], summed over dimensions."""
        z = (actions - self.mean) / self.std
        return (-0.5 * z * z - self.log_std - _HALF_LOG_2PI).sum(-1)

    def entropy(self) -> torch.Tensor:
        return (0.5 + _HALF_LOG_2PI + self.log_std).sum(-1)  # [B]

    def sample(self, generator: torch.Generator | None = None) -> torch.Tensor:
        m = self.mean
        noise = torch.randn(m.shape, generator=generator, device=m.device, dtype=m.dtype)
        return self.mean + self.std * noise  # unclipped: the ratio needs the action actually drawn

    def mode(self) -> torch.Tensor:
        return self.mean


class TanhGaussian:
    """SAC policy: u ~ N(mean, std), a = tanh(u) in (-1, 1)^D, log-std [B, D] clipped to [-20, 2]."""

    def __init__(self, mean: torch.Tensor, log_std: torch.Tensor):
        self.base = DiagGaussian(mean, log_std, SAC_LOG_STD_MIN, SAC_LOG_STD_MAX)

    def rsample(self, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Reparameterised (actions [B, D], log-probabilities [B])."""
        u = self.base.sample(generator)
        return torch.tanh(u), self.log_prob_pre_tanh(u)

    def log_prob_pre_tanh(self, u: torch.Tensor) -> torch.Tensor:
        # log|d tanh(u)/du| = log(1 - tanh²u) = 2 (log 2 - u - softplus(-2u)), stable for large |u|
        log_det = 2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))
        return self.base.log_prob(u) - log_det.sum(-1)

    def mode(self) -> torch.Tensor:
        return torch.tanh(self.base.mean)
