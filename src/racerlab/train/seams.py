"""The seams of `Trainer(collector=, logs=, learner=)`, written down: what a collection, a logs writer and a
learner must offer.

This machine's implementations are `train.worlds.LocalCollection` and `train.records.TrainingLogs`; the cluster's
are `cluster.training.ClusterCollection` and `cluster.training.WorkerLogs`; a taught model's are
`train.distill.PairedCollection` and `train.distill.DaggerLearner`. The default learner is the agent itself
(`train.loop.AgentLearner`: PPO's update, SAC's replay memory, all of it in the checkpoint). A test checks that each
has every method with the signature given here.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from racerlab.train.rollout import Rollout


@runtime_checkable
class Collection(Protocol):
    """Where a training's episodes come from."""

    def collect(self, agent, target_episodes: int, max_steps: int, first_episode_number: int = 0, *,
                deadline: float | None = None, tick=None, tick_s: float = 10.0) -> Rollout:
        """At least `target_episodes` whole episodes (at most `max_steps` steps kept), driven by `agent`; episodes
        are numbered from `first_episode_number`; `deadline` is a `time.perf_counter()` value to stop at; `tick`
        is called every `tick_s` seconds with the progress."""

    def before_iteration(self, iteration: int) -> None:
        """Called before each iteration's collection (a local run draws new generated tracks here)."""

    def state(self) -> dict:
        """What a checkpoint keeps to resume the collection (`TrainingState.collection`): JSON-able values under
        the collection's own keys."""

    def restore(self, saved: dict) -> None:
        """Resume from a checkpoint's `state()` (an empty dict for a fresh run or another collection's)."""

    def metrics(self, iteration: int) -> dict:
        """Extra metrics.jsonl keys of an iteration."""

    def close(self) -> None:
        """Release what the collection holds (the cluster's workers)."""


@runtime_checkable
class IterationLogs(Protocol):
    """What writes a training's records: simtrace, TrainingMetrics and metrics.jsonl."""

    def write_iteration(self, iteration: int, ro, evals, first_episode: int) -> None:
        """The iteration's simtrace and TrainingMetrics entries (its rollout `ro` and evaluation episodes)."""

    def append_metrics(self, entry: dict) -> None:
        """One metrics.jsonl line."""

    def truncate(self, iteration: int, episodes: int) -> None:
        """Forget what was logged after a checkpoint (iteration, episodes) a run resumes from."""

    def disk_bytes(self) -> int:
        """Bytes the logs take on disk."""

    def close(self) -> None:
        """Flush and close."""


@runtime_checkable
class Learner(Protocol):
    """What learns from each iteration's episodes. Every learner gets the trainer's health checks (`train.health`):
    after `learn`, the NaN guard (`finite()`, a `nonfinite` metric or a non-finite `losses/...` one), the collapse
    checks, and the rollback, which restores the `state_dict()` of the last committed iteration and halves `lr`.

    Besides the methods: `lr`, the learning rate a rollback halves (settable); `deadline`, set by the trainer: a
    `time.perf_counter()` value at which an update in progress ends after its step (`--minutes`); `rate`, where the
    rate is set (`train.health.RateSetting`), for the rollback's advice.
    """

    def learn(self, rollout) -> dict:
        """Learn from an iteration's `Rollout`; returns its metrics (metrics.jsonl keys, float values)."""

    def finite(self) -> bool:
        """True when every weight it trains is finite."""

    def state_dict(self) -> dict:
        """A snapshot (a deep copy) of what it trains, weights and optimiser, to roll back to."""

    def load_state_dict(self, state: dict) -> None:
        """Go back to a `state_dict()` snapshot."""

    def keep(self, iteration: int) -> None:
        """Called with each iteration's checkpoint, before it is written: keep on disk what the learner needs beyond
        the agent's weights (which the checkpoint holds) to resume; DAgger keeps its data set and its optimiser."""

    def resume(self, iteration: int) -> None:
        """Called when the run resumes from the checkpoint of `iteration` (0 for a fresh start): take back what
        `keep` kept up to it and forget what it kept after it."""
