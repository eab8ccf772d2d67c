"""One training run's parts, assembled in one place: the model folder's files, training.toml with the run's
overrides (the command line's flags), the reward behind its watchdog and caller, the world builder, the worlds
this process drives and the agent built for them.

`Trainer` (`trainer_parts`) and every Ray rollout worker (`cluster.worker`, with its own share of the run) call
`assemble`, so a worker's run is the trainer's run but for its share.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

from racerlab.errors import ConfigError
from racerlab.model import ModelFolder, TrainingConfig
from racerlab.reward import RewardCaller, RewardWatchdog
from racerlab.train.progress import Progress
from racerlab.train.worlds import WorldBuilder


def _check_flags(minutes, episodes, iterations, num_cars) -> None:
    """Command-line values the training cannot use: one line naming the flag."""
    for flag, value, least in (("--minutes", minutes, 0), ("--episodes", episodes, 0), ("--iterations", iterations, 0),
                               ("--cars", num_cars, 1)):
        if value is None:
            continue
        if not (isinstance(value, int | float) and math.isfinite(value)) or value < least:
            what = "a number >= 0 (0 = no limit)" if least == 0 else "at least 1"
            raise ConfigError(f"{flag} must be {what}, got {value!r}")


def apply_overrides(cfg: TrainingConfig, *, minutes=None, episodes=None, iterations=None, num_cars=None,
                    device=None, seed=None, tracks=None) -> TrainingConfig:
    _check_flags(minutes, episodes, iterations, num_cars)
    stop = cfg.stop
    stop = replace(stop, minutes=stop.minutes if minutes is None else float(minutes),
                   episodes=stop.episodes if episodes is None else int(episodes),
                   iterations=stop.iterations if iterations is None else int(iterations))
    run = cfg.run
    run = replace(run, num_cars=run.num_cars if num_cars is None else int(num_cars),
                  device=run.device if device is None else device, seed=run.seed if seed is None else int(seed))
    track = cfg.track if not tracks else replace(cfg.track, names=tuple(tracks))
    return replace(cfg, stop=stop, run=run, track=track)


def whole_run(base: TrainingConfig, overrides: dict) -> TrainingConfig:
    """The run's settings on one machine: training.toml with the flags applied."""
    return apply_overrides(base, **overrides)


@dataclass
class RunParts:
    """What one process of a training run is built from (`assemble`)."""

    folder: ModelFolder
    metadata: object  # model_metadata.json (`ModelMetadata`)
    hp: object  # hyperparameters.json (`Hyperparameters`)
    cfg: TrainingConfig  # training.toml with the overrides (and, in a worker, its share)
    overrides: dict
    watchdog: RewardWatchdog
    reward: RewardCaller
    builder: WorldBuilder
    worlds: list  # the worlds this process drives: a trainer's evaluation world, a worker's training worlds
    agent: object  # built for worlds[0]'s observation, on run.device, seeded with run.seed
    note: Callable[[str], None]  # tells the user (the watchdog's slow-reward line, the trainer's notes)
    started: float  # time.perf_counter() when the assembly began: --minutes counts the set-up too
    cpu_started: float  # time.process_time() then (the first lap's CPU seconds)
    progress: Progress | None = None  # the trainer's progress view, which keeps its notes; None in a worker


def assemble(model_dir, overrides: dict | None = None, *, note: Callable[[str], None],
             worlds: Callable[[WorldBuilder], list],
             config: Callable[[TrainingConfig, dict], TrainingConfig] = whole_run) -> RunParts:
    """The parts of a run of the model in `model_dir`: `config(training.toml, overrides)` gives its settings (a
    worker's share: `cluster.worker.worker_config`), `worlds(builder)` the worlds this process drives (the agent
    is built for the first one's observation), `note` is where the parts tell the user."""
    started, cpu = time.perf_counter(), time.process_time()
    overrides = dict(overrides or {})
    folder = ModelFolder(model_dir)
    folder.require()
    metadata, hp = folder.metadata(), folder.hyperparameters()
    cfg = config(folder.config(), overrides)
    watchdog = RewardWatchdog(folder.reward_function(), cfg.run.reward_budget_s, note)
    reward = RewardCaller(watchdog)
    builder = WorldBuilder(cfg, metadata, reward, track_flag=bool(overrides.get("tracks")))
    driven = list(worlds(builder))
    from racerlab.agent import make_agent  # torch: only where weights are built

    agent = make_agent(driven[0].observation.space, metadata, hp, device=cfg.run.device, seed=cfg.run.seed)
    return RunParts(folder, metadata, hp, cfg, overrides, watchdog, reward, builder, driven, agent, note, started, cpu)


def trainer_parts(model_dir, overrides: dict | None = None, *, progress: bool = True) -> RunParts:
    """A trainer's parts: the whole run's settings, the in-training evaluation's world, a progress view that
    prints (when `progress`) and keeps the run's notes."""
    view = Progress(enabled=progress)
    parts = assemble(model_dir, overrides, note=view.note, worlds=lambda builder: [builder.evaluation_world()])
    parts.progress = view
    return parts
