"""The health of a training run, judged after every update: the NaN guard, the collapse checks, the rollback to
the last good weights with a halved learning rate, and the learning-rate advice the run prints.

A rollback is counted and said (with its likely cause and fix) and recorded for the next metrics.jsonl line;
after MAX_ROLLBACKS the run stops with `TrainingDiverged`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from racerlab.agent.distributions import PPO_LOG_STD_MAX, PPO_LOG_STD_MIN
from racerlab.errors import RacerlabError

MAX_ROLLBACKS = 3
VALUE_LOSS_LIMIT = 1e5  # PPO learns returns over a running scale (agent.ppo): a loss past this is a learner gone wrong
MAX_SENSIBLE_REWARD = 1e3
COLLAPSED_ENTROPY = 0.05  # nats; a fresh discrete policy starts near ln(number of actions)
# nats; below this a discrete policy's softmax is saturated (gradients ~0): it cannot explore or learn again
# (lr 10 sat at "entropy 0.000" in issue 28); a policy that laps like that is left alone
PINNED_ENTROPY = 1e-3
KL_LIMIT = 2.0  # nats; PPO at sane learning rates moves the policy ~0.01-0.05 per update
AWS_DEFAULT_LR = 0.0003


class TrainingDiverged(RacerlabError):
    pass


@dataclass(frozen=True)
class RateSetting:
    """Where a learner's learning rate is set, for the advice: its key (`lr`, `teacher.lr`), the file's value, the
    file, and the rate to suggest when the file's is above it."""

    key: str
    value: float
    source: str
    default: float = AWS_DEFAULT_LR


class Health:
    """Watches a learner's updates (`train.seams.Learner`: PPO's or SAC's agent itself, or DAgger's fit of the
    student). `agent` is the model's agent (its policy's spread is checked), `rate` where the learner's rate is set,
    `reward_path` names the reward in the advice, `discrete` says whether the entropy check applies, `note(text)`
    tells the user."""

    def __init__(self, learner, agent, rate: RateSetting, reward_path, *, discrete: bool, note, model_path):
        self.learner = learner
        self.agent = agent
        self.rate = rate
        self.reward_path = reward_path
        self.discrete = discrete
        self.note = note
        self.model_path = model_path
        self.rollbacks = 0
        self.last_good = None  # the learner's state after the last committed iteration
        self.last_eval: float | None = None
        self.events: list[str] = []  # rollbacks since the last metrics line, written into the next one

    def sound(self, metrics, iteration: int) -> bool:
        """NaN guard: True when the update is sound; otherwise roll back and lower the learning rate."""
        bad = bool(metrics.get("nonfinite")) or not self.learner.finite() or any(
            isinstance(v, float) and not math.isfinite(v) for k, v in metrics.items() if k.startswith("losses/"))
        if bad:
            self.rollback("non-finite loss or weights", f"lower {self.rate.key} in {Path(self.rate.source).name} or "
                          "check the reward function's scale", iteration)
        return not bad

    def collapse(self, metrics, evals, rewards) -> tuple[str, str] | None:
        """(what happened, likely cause and fix) when the update collapsed the policy though every value is finite:
        the value loss exploded (rewards far too large), a continuous policy's spread was pushed onto its limit, one
        update moved the policy absurdly far (approx KL), a discrete policy's entropy reached ~0 short of a lap, or
        fell to near zero while its evaluation progress fell (a learning rate far too high). An iteration found
        sound becomes the yardstick for the next one's evaluation."""
        v = metrics.get("losses/value")
        if v is not None and v > VALUE_LOSS_LIMIT:
            top = float(np.max(np.abs(rewards))) if np.size(rewards) else 0.0
            if top > MAX_SENSIBLE_REWARD:
                return (f"value loss {v:.3g} (over {VALUE_LOSS_LIMIT:g})",
                        f"the reward scale: {self.reward_path} returned rewards up to {top:.3g}; keep them "
                        f"within about 0..{MAX_SENSIBLE_REWARD:g} per step")
            return (f"value loss {v:.3g} (over {VALUE_LOSS_LIMIT:g}) with rewards up to {top:.3g}",
                    self.lr_advice())
        ev = float(np.mean([e.progress for e in evals])) if evals else None
        # judged against the last *committed* evaluation: a collapsed one that was rolled back must not become the
        # yardstick, or the next collapse (same crash, same progress) is "not falling" and the run sits in it
        prev = self.last_eval
        falling = ev is None or (ev < prev if prev is not None else ev < 10.0)
        found = self._collapse(metrics, ev, falling)
        if found is None and ev is not None:
            self.last_eval = ev
        return found

    def _collapse(self, metrics, ev: float | None, falling: bool) -> tuple[str, str] | None:
        pinned = self.pinned_spread()
        if pinned:
            return pinned, self.lr_advice()
        kl = metrics.get("losses/approx_kl")
        # a far move counts only where the evaluation got worse (or there is none): a converged continuous
        # policy (std ~0.05) shows rare spikes of the approx KL from a few samples its mean moved away from
        # (40 nats once in 300 iterations of 6.7-6.9 s laps), and rolling those back undid good training
        if kl is not None and kl > KL_LIMIT and falling:
            return (f"the policy moved {kl:.3g} nats in one update (approx KL over {KL_LIMIT:g})", self.lr_advice())
        ent = metrics.get("losses/entropy")
        if not self.discrete or ent is None:
            return None
        if ent < PINNED_ENTROPY and (ev is None or ev < 100.0):
            where = "with no evaluation" if ev is None else f"while evaluation progress is {ev:.1f} %"
            return (f"entropy {ent:.3g}: one action certain in every state, so the policy cannot learn, {where}",
                    self.lr_advice())
        if ev is None:
            return None
        if ent < COLLAPSED_ENTROPY and falling:
            return (f"entropy {ent:.3g} (near zero) while evaluation progress fell to {ev:.1f} %", self.lr_advice())
        return None

    def pinned_spread(self) -> str | None:
        """What is wrong when a continuous PPO policy's log-std parameter left the range its distribution clamps it
        to: past the clamp its gradient is zero, so nothing brings it back and the policy drives pure noise (std
        e^3 = 20 where actions span [-1, 1]) or none at all, whatever the evaluation says. lr 10 did this in its first
        update on e958da9: the entropy then sat at the clamp's value (8.84 for two actions) and the run went on."""
        log_std = getattr(getattr(self.agent, "policy_net", None), "log_std", None)
        if self.discrete or log_std is None:
            return None
        values = log_std.detach().cpu().numpy()
        low, high = float(values.min()), float(values.max())
        if high >= PPO_LOG_STD_MAX:
            return f"the policy's log-std reached {high:.3g}, past its limit of {PPO_LOG_STD_MAX:g} (actions are noise)"
        if low <= PPO_LOG_STD_MIN:
            return f"the policy's log-std fell to {low:.3g}, past its limit of {PPO_LOG_STD_MIN:g} (no exploration)"
        return None

    def lr_advice(self) -> str:
        """The learning-rate advice, naming the file's rate (and the rate the rollbacks have halved it to): the
        setting's default (AWS's 0.0003 for PPO and SAC) when the file's is higher, else a tenth of the file's."""
        r, ours = self.rate, self.learner.lr
        now = f" (halved to {ours:g} by rollbacks)" if ours < r.value else ""
        hint = r.default if r.value > r.default else r.value / 10
        return f"the learning rate: {r.key} {r.value:g} in {r.source}{now} is too high; try {hint:g} or lower"

    def rollback(self, what: str, cause: str, iteration: int) -> None:
        """Restore the last good weights, halve the learning rate, say so and record it for metrics.jsonl;
        after MAX_ROLLBACKS stop with TrainingDiverged."""
        self.rollbacks += 1
        lr = self.learner.lr
        self.learner.load_state_dict(self.last_good)
        self.learner.lr = lr / 2
        text = (f"{what} in iteration {iteration + 1}: rolled back to the last good weights, learning rate "
                f"{lr:g} → {lr / 2:g} ({self.rollbacks}/{MAX_ROLLBACKS}); likely cause: {cause}")
        self.note(text)
        self.events.append(text)
        if self.rollbacks >= MAX_ROLLBACKS:
            raise TrainingDiverged(f"{self.model_path}: training diverged: {MAX_ROLLBACKS} rollbacks, the last after "
                                   f"{what}; likely cause: {cause}")

    def take_events(self) -> list[str]:
        events, self.events = self.events, []
        return events
