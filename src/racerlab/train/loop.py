"""`train(model_dir)`: the iteration loop — collect episodes, update, evaluate, checkpoint, log.

One iteration, as DeepRacer runs it (facts §6, §9): the cars drive whole training episodes with
the current policy (`num_episodes_between_training`, or one per car when there are more cars);
the agent learns from them (`agent.learn(rollout)`: PPO's update, SAC's replay memory); a few
greedy evaluation episodes pick the best checkpoint; the checkpoint, the AWS-format logs and
racerlab's metrics are written atomically. A training stopped at any moment (Ctrl-C, kill -9,
a reward function that raises) resumes from the last complete iteration.
"""

from __future__ import annotations

import math
import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from racerlab.errors import ConfigError, RacerlabError, TrackError
from racerlab.model import ModelFolder, TrainingConfig, check_compatible, nonfinite_tensors
from racerlab.sim import StartRules, World
from racerlab.sim.reward import RewardCaller
from racerlab.track import load as load_track
from racerlab.train.evaluation import eval_metric, is_better, run_greedy_episodes
from racerlab.train.progress import Progress
from racerlab.train.records import TrainingLogs
from racerlab.train.rollout import Collector
from racerlab.train.watchdog import RewardWatchdog

MAX_ROLLBACKS = 3
VALUE_LOSS_LIMIT = 1e5  # a value loss past this means returns of ~1e4 per episode or more: rewards out of scale
MAX_SENSIBLE_REWARD = 1e3
COLLAPSED_ENTROPY = 0.05  # nats; a fresh discrete policy starts near ln(number of actions)
KL_LIMIT = 2.0  # nats; PPO at sane learning rates moves the policy ~0.01-0.05 per update
STATE_FORMAT = "racerlab.checkpoint/1"


@contextmanager
def _ctrl_c_after():
    """Hold a Ctrl-C (SIGINT) that arrives inside the block and raise it when the block ends, so an iteration is
    either wholly on disk or not at all (a checkpoint without its metrics line showed an iteration too few)."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield
        return
    held = []
    signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if held:
        raise KeyboardInterrupt


class TrainingDiverged(RacerlabError):
    pass


@dataclass
class TrainResult:
    model_dir: Path
    iterations: int = 0
    episodes: int = 0
    env_steps: int = 0
    wall_seconds: float = 0.0
    best_checkpoint: str | None = None
    best_metric: float | None = None
    best_lap_time: float = math.nan
    first_lap: dict | None = None  # iteration, wall seconds and env steps of the first completed eval lap
    stopped: str = ""
    history: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # what the run said besides the iteration lines


@dataclass
class _State:
    iteration: int = 0
    episodes: int = 0
    env_steps: int = 0
    train_steps: int = 0  # kept (learned-on) steps: the S in N_Step-S
    best_name: str | None = None
    best_metric: float | None = None
    best_lap_time: float = math.nan
    rollbacks: int = 0
    starts: list[int] = field(default_factory=list)  # each world's round-robin counter
    first_lap: dict | None = None


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


class Trainer:
    """Holds the pieces of one training run; `run()` iterates until a stop condition."""

    def __init__(self, model_dir, progress: bool = True, stop_at_first_lap: bool = False, **overrides):
        self.t_created = time.perf_counter()  # --minutes counts the set-up (tracks, compiling the simulator) too
        self.stop_at_first_lap = stop_at_first_lap
        self.folder = ModelFolder(model_dir)
        self.folder.require()
        self.metadata = self.folder.metadata()
        self.hp = self.folder.hyperparameters()
        self.cfg = apply_overrides(self.folder.config(), **overrides)
        self._track_flag = bool(overrides.get("tracks"))
        self.notes: list[str] = []
        self.progress = Progress(enabled=progress)
        self.watchdog = RewardWatchdog(self.folder.reward_function(), self.cfg.run.reward_budget_s, self._note)
        self.reward = RewardCaller(self.watchdog)
        self.draw = 0  # which draw of generated tracks the worlds hold
        self.worlds = self._make_worlds()
        self.collector = Collector(self.worlds)
        r = self.cfg.randomise
        self.eval_world = self._make_world(self.cfg.track.names[0], self._eval_cars(), seed=10_007,
                                           randomise=r if r.evaluation else None)
        from racerlab.agent import make_agent

        self.agent = make_agent(self.worlds[0].observation.space, self.metadata, self.hp, device=self.cfg.run.device,
                                seed=self.cfg.run.seed)
        self._set_threads()  # after the agent is built: the thread count depends on its networks
        self.logs = TrainingLogs(self.folder.path, self.cfg)
        self.state = _State()
        self.deadline: float | None = None  # perf_counter time of --minutes' end
        self.events: list[str] = []  # rollbacks since the last metrics line, written into the next one
        self.last_eval: float | None = None
        self.last_good = None

    # ---- set-up ------------------------------------------------------------------------------
    def _set_threads(self):
        import torch

        from racerlab.agent.common import learner_threads

        torch.set_num_threads(learner_threads(self.agent.networks(), self.cfg.run.threads))
        if self.cfg.run.threads and hasattr(self.agent, "adapt_threads"):
            self.agent.adapt_threads = False  # a count the user chose is kept
        self.agent.threads = self.cfg.run.threads  # PPO sets it again before each update

    def _load_track(self, name):
        try:
            return load_track(name)
        except TrackError as exc:
            where = "--track" if self._track_flag else f"{self.cfg.source}: track.names"
            raise TrackError(f"{where}: {exc}") from None

    def _make_world(self, track, cars, seed, randomise=None):
        r = self.cfg.track
        start = StartRules(change_start=r.change_start, advance=r.round_robin_advance, offset=r.start_offset,
                           reverse=r.reverse, alternate_direction=r.alternate_direction)
        track = self._load_track(track) if isinstance(track, str) else track
        return World(track, cars, self.metadata, self.reward, self.cfg.run.observation, start=start,
                     max_episode_steps=self.cfg.run.max_episode_steps, reward_order=self.cfg.run.reward_order,
                     seed=seed, race=self.cfg.race, randomise=randomise,
                     car=self.cfg.car)  # issue 24: the [car] table's simulator car (steps jitter in training)

    def _eval_cars(self) -> int:
        """Cars of the greedy evaluation world: one per evaluation episode; a head-to-model race pairs its cars,
        so an odd count gains one (each car still drives one judged episode)."""
        n = max(self.cfg.evaluation.episodes, 1)
        return n + n % 2 if self.cfg.race.head_to_model else n

    def _make_worlds(self):
        tracks = generated_tracks(self.cfg.track, self.cfg.run.seed, self.draw) or self.cfg.track.names
        n = self.cfg.run.num_cars
        counts = [n // len(tracks) + (1 if k < n % len(tracks) else 0) for k in range(len(tracks))]
        if self.cfg.race.head_to_model:  # the cars race in pairs: every track gets whole pairs
            if n % 2 or n < 2 * len(tracks):
                raise ConfigError(f"{self.cfg.source}: run.num_cars (or --cars) {n}: a head_to_model race pairs the "
                                  f"cars, so it needs an even number, at least 2 per track "
                                  f"({len(tracks)} track{'s' if len(tracks) != 1 else ''})")
            pairs = n // 2
            counts = [2 * (pairs // len(tracks) + (1 if k < pairs % len(tracks) else 0)) for k in range(len(tracks))]
        pairs = enumerate(zip(tracks, counts, strict=True))
        seed = self.cfg.run.seed + 1000 * self.draw
        return [self._make_world(t, c, seed + k, self.cfg.randomise) for k, (t, c) in pairs]

    def _redraw_if_due(self):
        """New generated tracks every `track.regenerate_every` iterations (the draw follows the iteration
        number, so a resumed run drives the tracks it would have driven)."""
        every = self.cfg.track.regenerate_every
        if not self.cfg.track.generated or not every or self.state.iteration // every == self.draw:
            return
        self.draw = self.state.iteration // every
        next_uid = self.collector.next_uid
        self.worlds = self._make_worlds()
        self.collector = Collector(self.worlds)
        self.collector.next_uid = next_uid

    # ---- checkpoints -------------------------------------------------------------------------
    def _checkpoint_state(self) -> dict:
        s = self.state
        return {"format": STATE_FORMAT, "agent": self.agent.state_dict(), "metadata": self.metadata.to_json(),
                "hyperparameters": self.hp.to_json(), "observation": self.worlds[0].observation.name,
                "iteration": s.iteration, "episodes": s.episodes, "env_steps": s.env_steps,
                "train_steps": s.train_steps, "best_name": s.best_name, "best_metric": s.best_metric,
                "best_lap_time": s.best_lap_time, "rollbacks": s.rollbacks,
                "starts": [w.sim.episodes_started for w in self.worlds], "first_lap": s.first_lap,
                "saved_at": time.time()}

    def _resume_or_start(self):
        cps = self.folder.checkpoints()
        if not cps:
            info = self.folder.save_checkpoint(self._checkpoint_state(), 0, 0)
            self.folder.update_index(info, float("nan"), None, None)
            self.last_good = self.agent.state_dict()
            return False
        info, ck = self._newest_readable(cps)
        from racerlab.model import parse_model_metadata

        check_compatible(parse_model_metadata(ck["metadata"], f"{info.name} (checkpoint)"), self.metadata,
                         str(self.folder.metadata_path))
        self._check_observation(ck, info)
        self.agent.load_state_dict(ck["agent"])
        self._apply_edits(ck, info)
        s = self.state
        s.iteration, s.episodes, s.env_steps = ck["iteration"], ck["episodes"], ck["env_steps"]
        s.train_steps = ck.get("train_steps", info.steps)
        s.best_name, s.best_metric = ck.get("best_name"), ck.get("best_metric")
        s.best_lap_time, s.rollbacks = ck.get("best_lap_time", math.nan), ck.get("rollbacks", 0)
        s.first_lap = ck.get("first_lap")
        for w, n in zip(self.worlds, ck.get("starts") or [], strict=False):
            w.sim.episodes_started = int(n)
        self.folder.drop_after(s.iteration)
        self.logs.truncate(s.iteration, s.episodes)
        self.last_good = self.agent.state_dict()
        return not ck.get("cloned", False)

    def _check_observation(self, ck, info):
        trained, now = ck.get("observation"), self.worlds[0].observation.name
        if trained and trained != now:
            raise ConfigError(f"{self.cfg.source}: run.observation is '{now}' but {info.name} was trained with "
                              f"'{trained}'; the network's inputs cannot change: set it back or clone into a new model")

    def _apply_edits(self, ck, info):
        """Hyperparameters edited since the checkpoint take effect, and the run says which. The agent is built
        from the current hyperparameters.json; only lr is also in the saved agent state, so the edited value is
        put back. A checkpoint that records none (older racerlab, or a clone) takes the file's lr."""
        saved = ck.get("hyperparameters")
        now = self.hp.to_json()
        if saved is None:
            saved = {**now, "lr": self.agent.lr} if not ck.get("cloned") and ck.get("rollbacks", 0) == 0 else now
        changed = [k for k in now if k in saved and saved[k] != now[k]]
        if "lr" in changed or ck.get("cloned"):
            self.agent.lr = self.hp.lr
        if changed:
            edits = ", ".join(f"{k} {saved[k]!r} → {now[k]!r}" for k in changed)
            self._note(f"{self.hp.source}: changed since checkpoint {info.name}, now in effect: {edits}")

    def _note(self, text: str) -> None:
        self.notes.append(text)
        self.progress.note(text)

    def _newest_readable(self, cps):
        """The newest checkpoint that loads; a damaged newer file is reported and skipped."""
        for info in reversed(cps):
            try:
                ck = self.folder.load_checkpoint(info)
            except RacerlabError as exc:
                self._note(f"skipping {info.name}: {exc}")
                continue
            bad = nonfinite_tensors(ck.get("agent", {}))
            if not bad:
                return info, ck
            self._note(f"skipping {self.folder.checkpoint_path(info)}: non-finite weights ({bad[0]}"
                       f"{f' and {len(bad) - 1} more' if len(bad) > 1 else ''}); resuming from an older checkpoint")
        raise RacerlabError(f"{self.folder.checkpoints_dir}: no readable checkpoint with finite weights; remove the "
                            "folder's checkpoints/ to start over")

    # ---- one iteration -----------------------------------------------------------------------
    def _guard(self, metrics) -> bool:
        """NaN guard: True when the update is sound; otherwise roll back and lower the learning rate."""
        bad = bool(metrics.get("nonfinite")) or not self.agent.finite() or any(
            isinstance(v, float) and not math.isfinite(v) for k, v in metrics.items() if k.startswith("losses/"))
        if bad:
            self._rollback("non-finite loss or weights", "lower lr in hyperparameters.json or check the reward "
                           "function's scale")
        return not bad

    def _collapse(self, metrics, evals, rewards) -> tuple[str, str] | None:
        """(what happened, likely cause and fix) when the update collapsed the policy though every value is finite:
        the value loss exploded (rewards far too large), one update moved the policy absurdly far (approx KL), or a
        discrete policy's entropy fell to near zero while its evaluation progress fell (a learning rate far too
        high)."""
        v = metrics.get("losses/value")
        if v is not None and v > VALUE_LOSS_LIMIT:
            top = float(np.max(np.abs(rewards))) if np.size(rewards) else 0.0
            if top > MAX_SENSIBLE_REWARD:
                return (f"value loss {v:.3g} (over {VALUE_LOSS_LIMIT:g})",
                        f"the reward scale: {self.folder.reward_path} returned rewards up to {top:.3g}; keep them "
                        f"within about 0..{MAX_SENSIBLE_REWARD:g} per step")
            return (f"value loss {v:.3g} (over {VALUE_LOSS_LIMIT:g}) with rewards up to {top:.3g}",
                    self._lr_cause())
        ev = float(np.mean([e.progress for e in evals])) if evals else None
        prev, self.last_eval = self.last_eval, ev if ev is not None else self.last_eval
        falling = ev is None or (ev < prev if prev is not None else ev < 10.0)
        kl = metrics.get("losses/approx_kl")
        # a far move counts only where the evaluation got worse (or there is none): a converged continuous
        # policy (std ~0.05) shows rare spikes of the approx KL from a few samples its mean moved away from
        # (40 nats once in 300 iterations of 6.7-6.9 s laps), and rolling those back undid good training
        if kl is not None and kl > KL_LIMIT and falling:
            return (f"the policy moved {kl:.3g} nats in one update (approx KL over {KL_LIMIT:g})",
                    self._lr_cause())
        ent = metrics.get("losses/entropy")
        if self.metadata.action_space_type != "discrete" or ent is None or ev is None:
            return None
        if ent < COLLAPSED_ENTROPY and falling:
            return (f"entropy {ent:.3g} (near zero) while evaluation progress fell to {ev:.1f} %",
                    self._lr_cause())
        return None

    def _lr_cause(self) -> str:
        """The learning-rate advice, naming the file's rate (and the rate the rollbacks have halved it to): AWS's
        default 0.0003 when the file's is higher, else a tenth of the file's."""
        lr, ours = self.hp.lr, self.agent.lr
        now = f" (halved to {ours:g} by rollbacks)" if ours < lr else ""
        hint = 0.0003 if lr > 0.0003 else lr / 10
        return f"the learning rate: lr {lr:g} in {self.hp.source}{now} is too high; try {hint:g} or lower"

    def _rollback(self, what: str, cause: str) -> None:
        """Restore the last good weights, halve the learning rate, say so and record it for metrics.jsonl;
        after MAX_ROLLBACKS stop with TrainingDiverged."""
        s = self.state
        s.rollbacks += 1
        lr = self.agent.lr
        self.agent.load_state_dict(self.last_good)
        self.agent.lr = lr / 2
        text = (f"{what} in iteration {s.iteration + 1}: rolled back to the last good weights, learning rate "
                f"{lr:g} → {lr / 2:g} ({s.rollbacks}/{MAX_ROLLBACKS}); likely cause: {cause}")
        self._note(text)
        self.events.append(text)
        if s.rollbacks >= MAX_ROLLBACKS:
            raise TrainingDiverged(f"{self.folder.path}: training diverged: {MAX_ROLLBACKS} rollbacks, the last after "
                                   f"{what}; likely cause: {cause}")

    def _evaluate(self):
        if self.cfg.evaluation.episodes == 0:
            return []
        n = self.eval_world.sim.num_cars
        offset = self.cfg.track.start_offset
        starts = np.mod(offset + np.arange(n) / n, 1.0)
        return run_greedy_episodes(self.agent, self.eval_world, starts)

    def _record_best(self, evals, info, t_start):
        s = self.state
        metric_name = self.cfg.evaluation.best_model_metric
        value = eval_metric(evals, metric_name)
        if is_better(metric_name, value, s.best_metric):
            s.best_name, s.best_metric = info.name, value
        laps = [e.lap_time for e in evals if e.status == "lap_complete"]
        if laps:
            s.best_lap_time = min(laps) if math.isnan(s.best_lap_time) else min(s.best_lap_time, min(laps))
            if s.first_lap is None:
                s.first_lap = {"iteration": s.iteration, "wall_seconds": time.perf_counter() - t_start,
                               "env_steps": s.env_steps}
        return value

    def iterate(self, t_start: float) -> dict:
        s = self.state
        self._redraw_if_due()
        target = max(self.hp.num_episodes_between_training, self.cfg.run.num_cars)
        ro = self.collector.collect(self.agent, target, self.cfg.run.max_steps_per_iteration,
                                    first_episode_number=s.episodes, deadline=self.deadline, tick=self.progress.tick)
        if ro.cut and not ro.episodes:
            s.env_steps += ro.env_steps
            self._note("time limit reached while collecting: no episode had ended, so this partial iteration is "
                       "dropped; the last complete iteration is kept")
            return {}
        t_learn = time.perf_counter()
        metrics = self.agent.learn(ro)
        learn_s = time.perf_counter() - t_learn
        s.env_steps += ro.env_steps
        if not self._guard(metrics):
            return {}
        past = self.deadline is not None and time.perf_counter() >= self.deadline
        evals = [] if ro.cut or past else self._evaluate()  # at the time limit: learn and save, no evaluation
        collapsed = self._collapse(metrics, evals, ro.rewards)
        if collapsed:
            self._rollback(*collapsed)
            return {}
        with _ctrl_c_after():  # the iteration's logs, checkpoint and metrics line are written together
            return self._commit(ro, evals, metrics, learn_s, t_start)

    def _commit(self, ro, evals, metrics, learn_s, t_start) -> dict:
        s = self.state
        s.iteration += 1
        s.episodes += len(ro.episodes)
        s.train_steps += int(ro.rewards.size)
        from racerlab.model import CheckpointInfo

        info = CheckpointInfo(f"{s.iteration}_Step-{s.train_steps}.pt", s.iteration, s.train_steps)
        value = self._record_best(evals, info, t_start)
        self.logs.write_iteration(s.iteration, ro, evals, s.episodes - len(ro.episodes))
        state = self._checkpoint_state()
        saved = self.folder.save_checkpoint(state, s.iteration, s.train_steps)
        best = next((c for c in self.folder.checkpoints() if c.name == s.best_name), None)
        self.folder.update_index(saved, value, best, s.best_metric)
        self.folder.prune(best)
        self.last_good = state["agent"]  # the snapshot just saved (a deep copy), not a second one
        entry = self._summary(ro, evals, metrics, learn_s, value)
        self.logs.append_metrics(entry)
        return entry

    def _summary(self, ro, evals, metrics, learn_s, value) -> dict:
        s = self.state
        eps = ro.episodes
        laps = [e.lap_time for e in eps if e.status == "lap_complete"]
        return {
            "iteration": s.iteration, "episodes": s.episodes, "env_steps": s.env_steps, "train_steps": s.train_steps,
            "time": time.time(), "collect_seconds": round(ro.seconds, 4), "learn_seconds": round(learn_s, 4),
            "charts/env_steps_per_s": ro.env_steps / max(ro.seconds, 1e-9),
            "charts/mean_reward": float(np.mean([e.reward for e in eps])) if eps else 0.0,
            "charts/completion": float(np.mean([min(e.progress, 100.0) for e in eps])) if eps else 0.0,
            "charts/laps": len(laps), "charts/best_lap_train": min(laps) if laps else None,
            "eval/mean_progress": float(np.mean([e.progress for e in evals])) if evals else None,
            "eval/laps": sum(e.status == "lap_complete" for e in evals),
            "eval/best_lap": min((e.lap_time for e in evals if e.status == "lap_complete"), default=None),
            "eval/metric": value, "best/lap_time": None if math.isnan(s.best_lap_time) else s.best_lap_time,
            "best/checkpoint": s.best_name, "lr": self.agent.lr, "logs/disk_bytes": self.logs.disk_bytes(),
            "rollbacks": s.rollbacks, "events": self._take_events(),
            **{k: float(v) for k, v in metrics.items()},
        }

    def _take_events(self) -> list[str]:
        events, self.events = self.events, []
        return events

    # ---- the loop ----------------------------------------------------------------------------
    def _limit_reached(self, t_start: float, start_iteration: int, start_episodes: int) -> str:
        """The stop conditions given (flags or training.toml); with none, AWS's term_cond_max_episodes."""
        stop, s = self.cfg.stop, self.state
        if stop.minutes and time.perf_counter() - t_start >= stop.minutes * 60:
            return f"time limit of {stop.minutes:g} min"
        max_eps = stop.episodes or (0 if stop.minutes or stop.iterations else self.hp.term_cond_max_episodes)
        if max_eps and s.episodes - start_episodes >= max_eps:
            return f"episode limit of {max_eps}"
        if stop.iterations and s.iteration - start_iteration >= stop.iterations:
            return f"iteration limit of {stop.iterations}"
        if self.stop_at_first_lap and s.first_lap is not None:
            return "first complete evaluation lap"
        return ""

    def run(self) -> TrainResult:
        with self.folder.lock(), self.watchdog:
            return self._run()

    def _run(self) -> TrainResult:
        t_start = self.t_created
        self.deadline = t_start + self.cfg.stop.minutes * 60 if self.cfg.stop.minutes else None
        self.agent.deadline = self.deadline  # the update in progress at the deadline ends after its minibatch
        resumed = self._resume_or_start()
        s = self.state
        start_iteration, start_episodes = s.iteration, s.episodes
        self.progress.start(self, resumed)
        result = TrainResult(self.folder.path)
        try:
            while not (reason := self._limit_reached(t_start, start_iteration, start_episodes)):
                entry = self.iterate(t_start)
                if entry:
                    result.history.append(entry)
                    self.progress.iteration(entry, self._eta(t_start, start_episodes, start_iteration))
            result.stopped = reason
        except KeyboardInterrupt:
            result.stopped = "interrupted (Ctrl-C); the last complete iteration is saved"
        finally:
            self.logs.close()
        result.iterations, result.episodes, result.env_steps = s.iteration, s.episodes, s.env_steps
        result.wall_seconds = time.perf_counter() - t_start
        result.best_checkpoint, result.best_metric = s.best_name, s.best_metric
        result.best_lap_time, result.first_lap = s.best_lap_time, s.first_lap
        result.notes = self.notes
        self.progress.finish(result)
        return result

    def _eta(self, t_start, start_episodes, start_iteration) -> float | None:
        stop, s = self.cfg.stop, self.state
        elapsed = time.perf_counter() - t_start
        if stop.minutes:
            return max(stop.minutes * 60 - elapsed, 0.0)
        if stop.iterations and s.iteration > start_iteration:
            done_it = s.iteration - start_iteration
            return elapsed / done_it * max(stop.iterations - done_it, 0)
        max_eps = stop.episodes or (0 if stop.iterations else self.hp.term_cond_max_episodes)
        done = s.episodes - start_episodes
        if max_eps and done:
            return elapsed / done * max(max_eps - done, 0)
        return None


def generated_tracks(settings, seed: int, draw: int) -> list:
    """The generated training tracks of draw number `draw` (none unless `track.generated` is set)."""
    if not settings.generated:
        return []
    from racerlab.track.generate import generate_many

    return generate_many(seed * 7919 + draw, settings.generated,
                         (settings.generated_min_length, settings.generated_max_length),
                         (settings.generated_min_width, settings.generated_max_width), settings.generated_min_radius,
                         prefix=f"generated_{draw}")


def train(model_dir, *, progress: bool = True, stop_at_first_lap: bool = False, **overrides) -> TrainResult:
    """Train the model in `model_dir` (resuming if it has checkpoints). Keyword overrides: minutes,
    episodes, iterations, num_cars, device, seed, tracks."""
    return Trainer(model_dir, progress=progress, stop_at_first_lap=stop_at_first_lap, **overrides).run()
