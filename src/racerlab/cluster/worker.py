"""One rollout worker: a batched `World` (or one per track) and a CPU copy of the policy.

The class is plain Python; `racerlab.cluster.collector` makes it a Ray actor. It assembles its parts with the
trainer's `racerlab.train.assemble` (settings, reward watchdog and caller, worlds, agent), so a worker's worlds are
exactly those `racerlab train` would build, with the worker's share of the cars, its own seed and its own
round-robin start offset (DRfC gives each robomaker its own start counter).
"""

from __future__ import annotations

import os
from dataclasses import replace
from functools import partial

from racerlab.train import apply_overrides, assemble
from racerlab.train.rollout import Collector

_LEARNER_ONLY = ("optimizer", "generator")  # state keys a worker keeps its own of
WORKER_SEED_STRIDE = 1_009  # worker k's run.seed is the model's + 1009 k: apart from the draws' 1000 strides


def broadcast_state(agent) -> dict:
    """What the learner sends each iteration: the network weights (on the CPU, whatever device the learner
    uses), without optimizer or random state."""
    return _on_cpu({k: v for k, v in agent.state_dict().items() if not any(w in k for w in _LEARNER_ONLY)})


def _on_cpu(obj):
    if isinstance(obj, dict):
        return {k: _on_cpu(v) for k, v in obj.items()}
    return obj.cpu() if hasattr(obj, "cpu") else obj


def worker_tracks(names: tuple[str, ...], index: int, workers: int) -> tuple[str, ...]:
    """Worker `index`'s tracks: its own slice of the list when there are at least as many tracks as
    workers (DRfC's multi-config: one track per worker), otherwise one track each, in turn."""
    if len(names) >= workers:
        return tuple(names[index::workers])
    return (names[index % len(names)],)


def worker_cars(num_cars: int, index: int, workers: int, unit: int = 1) -> int:
    """Worker `index`'s share of the cars (at least one car each), in whole groups of `unit` cars (2 for a
    head_to_model race, whose cars race in pairs)."""
    groups = num_cars // unit
    return unit * max(1, groups // workers + (1 if index < groups % workers else 0))


def worker_config(base, overrides: dict, *, index: int, workers: int):
    """Worker `index`'s settings: its [[worker]] table, then the flags, then its share of the run (its tracks, cars,
    seed and round-robin start offset; on the CPU)."""
    cfg = apply_overrides(base.for_worker(index), **overrides)
    r = cfg.track
    own = base.worker_sets(index, "track", "names") and not overrides.get("tracks")
    track = replace(r, names=r.names if own else worker_tracks(r.names, index, workers),
                    start_offset=(r.start_offset + index / workers) % 1.0)
    unit = 2 if cfg.race.head_to_model else 1
    run = replace(cfg.run, num_cars=worker_cars(cfg.run.num_cars, index, workers, unit),
                  seed=cfg.run.seed + WORKER_SEED_STRIDE * index, device="cpu")
    return replace(cfg, track=track, run=run)


class RolloutWorker:
    """Collects whole training episodes with the weights the learner broadcasts."""

    def __init__(self, model_dir: str, index: int, workers: int, overrides: dict):
        import torch

        torch.set_num_threads(1)
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        self.index = index
        # the trainer's assembly with this worker's share; generated tracks ([track] generated): its first draw stays
        parts = assemble(model_dir, overrides, note=lambda text: print(f"worker {index}: {text}", flush=True),
                         worlds=lambda builder: builder.training_worlds(),
                         config=partial(worker_config, index=index, workers=workers))
        self.metadata, self.cfg = parts.metadata, parts.cfg
        self.watchdog, self.reward = parts.watchdog, parts.reward
        self.worlds = parts.worlds
        self.collector = Collector(self.worlds)
        self.agent = parts.agent

    def describe(self) -> dict:
        return {"index": self.index, "pid": os.getpid(), "cars": self.cfg.run.num_cars,
                "tracks": list(self.cfg.track.names), "start_offset": self.cfg.track.start_offset,
                "reverse": self.cfg.track.reverse, "alternate_direction": self.cfg.track.alternate_direction}

    def set_starts(self, starts: list[int]) -> None:
        for w, n in zip(self.worlds, starts, strict=False):
            w.sim.episodes_started = int(n)

    def collect(self, weights: dict, target: int, max_steps: int, first_episode_number: int,
                seconds_left: float | None = None):
        """Load the broadcast weights, then collect `target` whole episodes (stopping after `seconds_left`
        seconds, when given, as `Collector.collect` does at its deadline); returns the `Rollout` (numpy arrays)
        and each world's round-robin counter."""
        import time

        state = self.agent.state_dict()
        state.update(weights)
        self.agent.load_state_dict(state)
        deadline = None if seconds_left is None else time.perf_counter() + max(seconds_left, 0.0)
        with self.watchdog:
            ro = self.collector.collect(self.agent, target, max_steps, first_episode_number=first_episode_number,
                                        deadline=deadline)
        return ro, [w.sim.episodes_started for w in self.worlds]
