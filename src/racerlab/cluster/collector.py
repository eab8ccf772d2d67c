"""Collection over Ray actors: the learner broadcasts weights, N workers return rollouts as arrays.

One iteration is DRfC's synchronous loop: the learner puts the weights in Ray's object store once,
each worker drives its share of the iteration's episodes (episode k goes to worker k mod N, as
DRfC's trainer asks for them), and the driver joins the rollouts in worker order. A worker that
dies mid-iteration costs its episodes only: the iteration completes with the others, the run
says so, and a fresh worker takes the dead one's place for the next iteration.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from racerlab.cluster.worker import RolloutWorker, broadcast_state
from racerlab.errors import RacerlabError
from racerlab.train.rollout import Rollout, concat_obs


def split_episodes(target: int, workers: int) -> list[int]:
    """Episodes per worker when episode k is served by worker k mod `workers` (DRfC)."""
    return [len(range(k, target, workers)) for k in range(workers)]


def connect(address: str | None = None, num_cpus: int | None = None):
    """`ray.init` once per process: an existing cluster at `address` (or RAY_ADDRESS), else a local one."""
    import ray

    if not ray.is_initialized():
        kwargs = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
        if address:
            ray.init(address=address, **kwargs)
        else:
            ray.init(num_cpus=num_cpus, **kwargs)
    return ray


@dataclass
class WorkerReport:
    """What happened to the workers in one iteration (the run prints the failures)."""

    finished: list[int] = field(default_factory=list)
    failed: dict[int, str] = field(default_factory=dict)
    weights_bytes: int = 0
    rollout_bytes: dict[int, int] = field(default_factory=dict)


class RayCollector:
    """The `Collector` interface (`collect(agent, target, max_steps, first_episode_number)`) over Ray actors."""

    def __init__(self, model_dir, workers: int, overrides: dict, address: str | None = None, note=print):
        if workers < 1:
            raise RacerlabError(f"--workers {workers}: need at least 1 worker; give --workers 2 or more")
        self.ray = connect(address)
        self.model_dir = str(model_dir)
        self.n = workers
        self.overrides = overrides
        self.note = note
        self.actor_class = self.ray.remote(num_cpus=1, max_restarts=0)(RolloutWorker)
        self.actors = [self._spawn(k) for k in range(workers)]
        self.info = self.ray.get([a.describe.remote() for a in self.actors])
        self.episodes = [0] * workers  # each worker counts its own episodes from 0, as the simulator does
        self.report = WorkerReport()
        self.starts: list[list[int]] = [[] for _ in range(workers)]

    def _spawn(self, k: int):
        return self.actor_class.remote(self.model_dir, k, self.n, self.overrides)

    def _revive(self, k: int) -> None:
        self.actors[k] = self._spawn(k)
        if self.starts[k]:
            self.actors[k].set_starts.remote(self.starts[k])

    def collect(self, agent, target_episodes: int, max_steps: int, first_episode_number: int = 0, *,
                deadline: float | None = None, tick=None, tick_s: float = 10.0) -> Rollout:
        """`target_episodes` whole episodes, split over the workers, driven with the learner's current weights.
        `deadline` (the driver's `time.perf_counter()` value) reaches each worker as the seconds left; `tick` is
        called at least every `tick_s` seconds while waiting, with the finished workers' episodes and steps."""
        t0 = time.perf_counter()
        weights = broadcast_state(agent)
        ref = self.ray.put(weights)
        report = WorkerReport(weights_bytes=_pickled_bytes(weights))
        counts = split_episodes(target_episodes, self.n)
        calls = {}
        for k, c in enumerate(counts):
            if c:
                steps = max(1, math.ceil(max_steps * c / max(target_episodes, 1)))
                left = None if deadline is None else deadline - time.perf_counter()
                calls[k] = self.actors[k].collect.remote(ref, c, steps, self.episodes[k], left)
        self._wait(calls, counts, t0, tick, tick_s)
        parts = []
        for k, fut in calls.items():
            try:
                ro, starts = self.ray.get(fut)
            except (self.ray.exceptions.RayActorError, self.ray.exceptions.WorkerCrashedError) as exc:
                report.failed[k] = type(exc).__name__
                self._revive(k)
                continue
            report.finished.append(k)
            report.rollout_bytes[k] = array_bytes(ro)
            self.starts[k] = starts
            parts.append((k, ro, self.episodes[k]))
            self.episodes[k] += len(ro.episodes)
        self.report = report
        if report.failed:
            lost = ", ".join(f"worker {k} ({why})" for k, why in report.failed.items())
            self.note(f"{lost} died during the iteration: it completes with {len(parts)} of {len(calls)} workers' "
                      "episodes; a fresh worker takes its place next iteration")
        if not parts:
            raise RacerlabError(f"{self.model_dir}: every rollout worker died in this iteration; check `ray status` "
                                "and the workers' logs under the Ray session folder, then resume the training")
        merged = merge_rollouts([ro for _, ro, _ in parts], first_episode_number, time.perf_counter() - t0)
        merged.parts = parts  # (worker, its rollout, its first episode number): the per-worker logs
        merged.cut = any(getattr(ro, "cut", False) for _, ro, _ in parts)
        return merged

    def _wait(self, calls: dict, counts: list[int], t0: float, tick, tick_s: float) -> None:
        """Block until every worker's call has finished (or failed), calling `tick` every `tick_s` seconds with
        the episodes of the workers done so far (their steps are not known before their rollouts are read)."""
        pending = list(calls.values())
        while pending:
            _, pending = self.ray.wait(pending, num_returns=len(pending), timeout=tick_s)
            if pending and tick is not None:
                waiting = set(pending)
                done = sum(counts[k] for k, fut in calls.items() if fut not in waiting)
                tick(done, sum(counts), None, time.perf_counter() - t0)

    def close(self) -> None:
        for a in self.actors:
            self.ray.kill(a)
        self.actors = []


def merge_rollouts(parts: list[Rollout], first_episode_number: int, seconds: float) -> Rollout:
    """The workers' rollouts as one, episodes in worker order, numbered on from `first_episode_number`."""
    learn = [p for p in parts if p.rewards.size]
    obs = concat_obs([p.obs for p in learn]) if learn else None
    keys = learn[0].record.keys() if learn else ()
    record = {k: np.concatenate([p.record[k] for p in learn]) for k in keys}
    trace, n = {}, first_episode_number
    traced = [p for p in parts if p.trace]
    for p in traced:
        local = p.trace["episode"] - p.trace["episode"].min() if p.trace["episode"].size else p.trace["episode"]
        shifted = dict(p.trace, episode=local + n)
        for key, v in shifted.items():
            trace.setdefault(key, []).append(v)
        n += len(p.episodes)
    trace = {k: np.concatenate(v) for k, v in trace.items()}
    finals = [p.final_obs for p in learn if p.final_obs is not None]

    def cat(name, dtype):
        arrays = [getattr(p, name) for p in learn]
        return np.concatenate(arrays) if arrays else np.zeros(0, dtype)

    ro = Rollout(obs, cat("actions", np.float64), record, cat("rewards", np.float32), cat("terminated", bool),
                 cat("truncated", bool), [e for p in parts for e in p.episodes], trace,
                 sum(p.env_steps for p in parts), seconds)
    ro.final_obs = concat_obs(finals) if finals else None
    return ro


def _pickled_bytes(obj) -> int:
    import pickle

    return len(pickle.dumps(obj, protocol=5))


def array_bytes(obj) -> int:
    """The bytes of every numpy array inside a rollout (what crosses the network, give or take pickling)."""
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if isinstance(obj, dict):
        return sum(array_bytes(v) for v in obj.values())
    if isinstance(obj, Rollout):
        return sum(array_bytes(getattr(obj, k)) for k in ("obs", "actions", "record", "rewards", "terminated",
                                                           "truncated", "trace", "final_obs"))
    return 0
