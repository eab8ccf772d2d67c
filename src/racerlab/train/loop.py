"""`Trainer`: the iteration loop — collect episodes, learn, evaluate, checkpoint, log — composed of a run's parts
(`train.parts`) and its seams (`train.seams`: the collection, the logs, the learner).

One iteration, as DeepRacer runs it (facts §6, §9): the cars drive whole training episodes with
the current policy (`num_episodes_between_training`, or one per car when there are more cars);
the learner learns from them (by default the agent itself, `agent.learn(rollout)`: PPO's update, SAC's replay
memory; a taught model's DAgger fit, `train.distill`); the health checks judge the update (`train.health`); a few
greedy evaluation episodes pick the best checkpoint; the checkpoint, the AWS-format logs and
racerlab's metrics are written atomically. A training stopped at any moment (Ctrl-C, kill -9,
a reward function that raises) resumes from the last complete iteration.
"""

from __future__ import annotations

import math
import signal
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from racerlab.errors import ConfigError, ModelRefused, RacerlabError
from racerlab.model import TrainingState
from racerlab.train.evaluation import eval_metric, laptime_tie_ms, pick_best, run_greedy_episodes
from racerlab.train.health import Health, RateSetting
from racerlab.train.parts import RunParts, trainer_parts
from racerlab.train.records import TrainingLogs
from racerlab.train.seams import Collection, IterationLogs, Learner
from racerlab.train.worlds import LocalCollection


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


@dataclass
class TrainResult:
    model_dir: Path
    iterations: int = 0
    episodes: int = 0
    env_steps: int = 0
    wall_seconds: float = 0.0
    best_checkpoint: str | None = None
    best_metric: float | None = None
    best_lap_time: float = math.nan  # the best eval lap (racerlab.logs.BEST_LAP_MEANING)
    best_lap_iteration: int | None = None
    first_lap: dict | None = None  # iteration, wall and CPU seconds and env steps of the first completed eval lap
    best_rule: str = "progress"  # [evaluation] best_model_metric: what picked best_checkpoint
    stopped: str = ""
    interrupted: bool = False  # Ctrl-C (SIGINT) ended it: the command exits 130, so `train && evaluate` stops
    car: str = ""  # which car drove (`CarParams.name`; also in every metrics.jsonl row)
    history: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # what the run said besides the iteration lines


MIN_LAP_MS = 1000.0  # no lap is under a second: a smaller "lap time" kept as the best was another rule's metric


def best_rule_of(ck: TrainingState, now: str) -> str | None:
    """The best_model_metric that picked the checkpoint's best (None: not known, taken as `now`'s). Checkpoints
    before it was recorded tell it apart only where the units do: a lap-time floor is the laptime rule's, and a
    best under a second is no lap time."""
    if ck.best_rule:
        return ck.best_rule
    if ck.best_floor is not None:
        return "laptime"
    if now == "laptime" and ck.best_metric is not None and ck.best_metric < MIN_LAP_MS:
        return "progress or reward"
    return None


class AgentLearner:
    """The default learner (`train.seams.Learner`): the agent itself, PPO's update or SAC's replay memory, its rate
    hyperparameters.json's lr."""

    def __init__(self, agent, hp):
        self.agent = agent
        self.rate = RateSetting("lr", hp.lr, str(hp.source))

    def learn(self, rollout) -> dict:
        return self.agent.learn(rollout)

    def finite(self) -> bool:
        return self.agent.finite()

    def state_dict(self) -> dict:
        return self.agent.state_dict()

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state)

    def keep(self, iteration: int) -> None:
        """Nothing: the agent's whole state (replay memory aside) is in the checkpoint."""

    def resume(self, iteration: int) -> None:
        """Nothing: the checkpoint's agent state is loaded by the trainer."""

    @property
    def lr(self) -> float:
        return getattr(self.agent, "lr_ceiling", self.agent.lr)  # PPO's rate before its steering (agent.ppo.KL_TARGET)

    @lr.setter
    def lr(self, value: float) -> None:
        self.agent.lr = value

    @property
    def deadline(self) -> float | None:
        return self.agent.deadline

    @deadline.setter
    def deadline(self, value: float | None) -> None:
        self.agent.deadline = value


class Trainer:
    """One training run, composed; `run()` iterates until a stop condition.

    `model` is the model folder (its parts are assembled here from it and the keyword `overrides`: minutes,
    episodes, iterations, num_cars, device, seed, tracks) or a `train.parts.RunParts` already assembled
    (`trainer_parts`), whose progress view then replaces `progress`. The seams (`train.seams`): `collector`, where
    the episodes come from (default: a `LocalCollection` of this machine's worlds; the cluster passes its Ray
    collection, a taught model its paired collection); `logs`, what writes the iteration's records (default:
    `TrainingLogs`; the cluster passes its per-worker logs); `learner`, what learns from the episodes (default:
    the agent itself; a taught model passes DAgger's fit). `before_run(trainer)` is a step run once, after the
    resume and before the first iteration (a taught model's teacher phase). Every learner goes through the same
    iteration and its health checks. The driver builds training worlds only for the local collection.
    """

    def __init__(self, model, progress: bool = True, stop_at_first_lap: bool = False, *,
                 collector: Collection | None = None, logs: IterationLogs | None = None,
                 learner: Learner | None = None, before_run: Callable[[Trainer], None] | None = None, **overrides):
        if isinstance(model, RunParts):
            if overrides:
                raise TypeError(f"Trainer: overrides {sorted(overrides)} belong in the parts' assembly")
            parts = model
        else:
            parts = trainer_parts(model, overrides, progress=progress)
        self.parts = parts
        self.t_created = parts.started  # --minutes counts the set-up (tracks, compiling the simulator) too
        self.cpu_created = parts.cpu_started  # the first lap's CPU seconds (a shared machine's wall time varies)
        self.stop_at_first_lap = stop_at_first_lap
        self.folder, self.metadata, self.hp, self.cfg = parts.folder, parts.metadata, parts.hp, parts.cfg
        self.progress = parts.progress
        self.watchdog, self.reward, self.builder = parts.watchdog, parts.reward, parts.builder
        self.eval_world, self.agent = parts.worlds[0], parts.agent
        self.collector = collector if collector is not None else LocalCollection(self.builder)
        self.learner = learner if learner is not None else AgentLearner(self.agent, self.hp)
        self.before_run = before_run
        self._set_threads()  # after the agent is built: the thread count depends on its networks
        self.logs = logs if logs is not None else TrainingLogs(self.folder.path, self.cfg)
        self.health = Health(self.learner, self.agent, self.learner.rate, self.folder.reward_path, note=self.note,
                             model_path=self.folder.path, discrete=self.metadata.action_space_type == "discrete")
        self.state = TrainingState(agent={}, train_steps=0)  # the counters; weights go in at each checkpoint
        self.deadline: float | None = None  # perf_counter time of --minutes' end

    @property
    def notes(self) -> list[str]:
        """What the run said besides the iteration lines."""
        return self.progress.notes

    # ---- set-up ------------------------------------------------------------------------------
    def _set_threads(self):
        import torch

        from racerlab.agent.common import learner_threads

        torch.set_num_threads(learner_threads(self.agent.networks(), self.cfg.run.threads))
        if self.cfg.run.threads and hasattr(self.agent, "adapt_threads"):
            self.agent.adapt_threads = False  # a count the user chose is kept
        self.agent.threads = self.cfg.run.threads  # PPO sets it again before each update

    # ---- checkpoints -------------------------------------------------------------------------
    def _checkpoint_state(self) -> TrainingState:
        return replace(self.state, agent=self.agent.state_dict(), metadata=self.metadata.to_json(),
                       best_rule=self.cfg.evaluation.best_model_metric,
                       hyperparameters=self.hp.to_json(), observation=self.eval_world.observation.name,
                       rollbacks=self.health.rollbacks, collection=self.collector.state(), saved_at=time.time())

    def _resume_or_start(self):
        cps = self.folder.checkpoints()
        if not cps:
            info = self.folder.save_state(self._checkpoint_state())
            self.folder.update_index(info, float("nan"), None, None)
            self.learner.resume(0)  # what a learner kept for checkpoints removed since is dropped
            self.health.last_good = self.learner.state_dict()
            return False
        info, ck = self._newest_readable(cps)
        self._check_observation(ck, info)
        self.agent.load_state_dict(ck.agent)
        self._apply_edits(ck, info)
        self.state = replace(ck, agent={}, cloned=False,
                             train_steps=info.steps if ck.train_steps is None else ck.train_steps)
        self.health.rollbacks = ck.rollbacks
        self._follow_best_rule(ck)
        self.collector.restore(ck.collection)
        self.folder.drop_after(ck.iteration)
        self.logs.truncate(ck.iteration, ck.episodes)
        self.learner.resume(ck.iteration)
        self.health.last_good = self.learner.state_dict()
        return not ck.cloned

    def _follow_best_rule(self, ck: TrainingState) -> None:
        """A best_model_metric changed since the checkpoint: the best metric kept (and the laptime rule's fastest
        lap) were the old rule's, in its own unit (a progress of 100.0 read as a lap time of 0.1 s froze the best
        checkpoint), so the new rule starts afresh at the next evaluation; until then the best checkpoint stays."""
        now, was = self.cfg.evaluation.best_model_metric, best_rule_of(ck, self.cfg.evaluation.best_model_metric)
        if was is None or was == now:
            return
        self.state.best_metric = self.state.best_floor = None
        self.note(f"{self.cfg.source}: evaluation.best_model_metric is {now}, and the best checkpoint so far "
                  f"({ck.best_name}) was picked by {was}: the next evaluation starts the pick by {now}")

    def _check_observation(self, ck: TrainingState, info):
        trained, now = ck.observation, self.eval_world.observation.name
        if trained and trained != now:
            raise ConfigError(f"{self.cfg.source}: run.observation is '{now}' but {info.name} was trained with "
                              f"'{trained}'; the network's inputs cannot change: set it back or clone into a new model")

    def _apply_edits(self, ck: TrainingState, info):
        """Hyperparameters edited since the checkpoint take effect, and the run says which. The agent is built
        from the current hyperparameters.json; only lr is also in the saved agent state, so the edited value is
        put back. A checkpoint that records none (older racerlab, or a clone) takes the file's lr."""
        saved = ck.hyperparameters
        now = self.hp.to_json()
        if saved is None:
            saved = {**now, "lr": self.agent.lr} if not ck.cloned and ck.rollbacks == 0 else now
        changed = [k for k in now if k in saved and saved[k] != now[k]]
        if "lr" in changed or ck.cloned:
            self.agent.lr = self.hp.lr
        if changed:
            edits = ", ".join(f"{k} {saved[k]!r} → {now[k]!r}" for k in changed)
            self.note(f"{self.hp.source}: changed since checkpoint {info.name}, now in effect: {edits}")

    def note(self, text: str) -> None:
        """Tell the user (the progress output) and keep it for the result's notes."""
        self.progress.note(text)

    def _newest_readable(self, cps):
        """The newest checkpoint the door lets through (`ModelFolder.open`); a newer one that cannot be read or holds
        non-finite weights is reported and skipped for an older one, one trained with other metadata stops the run."""
        for info in reversed(cps):
            try:
                return info, self.folder.open(info).state
            except ModelRefused as exc:
                if exc.reason not in (ModelRefused.UNREADABLE, ModelRefused.NONFINITE):
                    raise
                self.note(f"skipping {exc.path}: {exc.problem}; resuming from an older checkpoint")
        raise RacerlabError(f"{self.folder.checkpoints_dir}: no readable checkpoint with finite weights; remove the "
                            "folder's checkpoints/ to start over")

    # ---- one iteration -----------------------------------------------------------------------
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
        keep, s.best_floor = pick_best(metric_name, value, s.best_metric, s.best_floor,
                                       laptime_tie_ms(evals, self.eval_world.sim.dt))
        if keep:
            s.best_name, s.best_metric = info.name, value
        laps = [e.lap_time for e in evals if e.status == "lap_complete"]
        if laps:
            if math.isnan(s.best_lap_time) or min(laps) < s.best_lap_time:
                s.best_lap_time, s.best_lap_iteration = min(laps), s.iteration
            if s.first_lap is None:
                s.first_lap = {"iteration": s.iteration, "wall_seconds": time.perf_counter() - t_start,
                               "cpu_seconds": round(time.process_time() - self.cpu_created, 1),
                               "env_steps": s.env_steps}
        return value

    def iterate(self, t_start: float) -> dict:
        s = self.state
        self.collector.before_iteration(s.iteration)
        target = max(self.hp.num_episodes_between_training, self.cfg.run.num_cars)
        ro = self.collector.collect(self.agent, target, self.cfg.run.max_steps_per_iteration,
                                    first_episode_number=s.episodes, deadline=self.deadline, tick=self.progress.tick)
        if ro.cut and not ro.episodes:
            s.env_steps += ro.env_steps
            self.note("time limit reached while collecting: no episode had ended, so this partial iteration is "
                       "dropped; the last complete iteration is kept")
            return {}
        t_learn = time.perf_counter()
        with self.progress.heartbeat("updating the policy"):  # a camera update can take a minute on 2 cores
            metrics = self.learner.learn(ro)
        learn_s = time.perf_counter() - t_learn
        s.env_steps += ro.env_steps
        if not self.health.sound(metrics, s.iteration):
            return {}
        past = self.deadline is not None and time.perf_counter() >= self.deadline
        t_eval = time.perf_counter()
        with self.progress.heartbeat("evaluation episodes"):  # at the time limit: learn and save, no evaluation
            evals = [] if ro.cut or past else self._evaluate()
        seconds = (learn_s, time.perf_counter() - t_eval)
        collapsed = self.health.collapse(metrics, evals, ro.rewards)
        if collapsed:
            self.health.rollback(*collapsed, s.iteration)
            return {}
        with _ctrl_c_after():  # the iteration's logs, checkpoint and metrics line are written together
            return self._commit(ro, evals, metrics, seconds, t_start)

    def _commit(self, ro, evals, metrics, seconds, t_start) -> dict:
        s = self.state
        s.iteration += 1
        s.episodes += len(ro.episodes)
        s.train_steps += int(ro.rewards.size)
        value = self._record_best(evals, s.info, t_start)
        self.logs.write_iteration(s.iteration, ro, evals, s.episodes - len(ro.episodes))
        state = self._checkpoint_state()
        self.learner.keep(s.iteration)  # before the checkpoint: a checkpoint never lacks what its learner kept
        saved = self.folder.save_state(state)
        best = next((c for c in self.folder.checkpoints() if c.name == s.best_name), None)
        self.folder.update_index(saved, value, best, s.best_metric)
        self.folder.prune(best)
        self.health.last_good = self.learner.state_dict()
        entry = self._summary(ro, evals, metrics, seconds, value)
        self.logs.append_metrics(entry)
        return entry

    def _summary(self, ro, evals, metrics, seconds, value) -> dict:
        """The iteration's metrics.jsonl line; `seconds`: the learner's and the evaluation's."""
        s = self.state
        eps = ro.episodes
        laps = [e.lap_time for e in eps if e.status == "lap_complete"]
        return {
            "iteration": s.iteration, "episodes": s.episodes, "env_steps": s.env_steps, "train_steps": s.train_steps,
            "car": self.eval_world.sim.car_params.name,
            "time": time.time(), "collect_seconds": round(ro.seconds, 4), "learn_seconds": round(seconds[0], 4),
            "eval_seconds": round(seconds[1], 4),
            "charts/env_steps_per_s": ro.env_steps / max(ro.seconds, 1e-9),
            "charts/mean_reward": float(np.mean([e.reward for e in eps])) if eps else 0.0,
            "charts/completion": float(np.mean([min(e.progress, 100.0) for e in eps])) if eps else 0.0,
            "charts/laps": len(laps), "charts/best_lap_train": min(laps) if laps else None,
            "eval/mean_progress": float(np.mean([e.progress for e in evals])) if evals else None,
            "eval/laps": sum(e.status == "lap_complete" for e in evals),
            "eval/best_lap": min((e.lap_time for e in evals if e.status == "lap_complete"), default=None),
            "eval/metric": value, "best/lap_time": None if math.isnan(s.best_lap_time) else s.best_lap_time,
            "best/lap_iteration": s.best_lap_iteration,
            "best/checkpoint": s.best_name, "lr": self.agent.lr, "logs/disk_bytes": self.logs.disk_bytes(),
            "rollbacks": self.health.rollbacks, "events": self.health.take_events(),
            **{k: float(v) for k, v in metrics.items()}, **self.collector.metrics(s.iteration),
        }

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
        try:
            with self.folder.lock(), self.watchdog:
                return self._run()
        finally:
            self.collector.close()

    def _run(self) -> TrainResult:
        t_start = self.t_created
        self.deadline = t_start + self.cfg.stop.minutes * 60 if self.cfg.stop.minutes else None
        self.learner.deadline = self.deadline  # the update in progress at the deadline ends after its minibatch
        resumed = self._resume_or_start()
        s = self.state
        start_iteration, start_episodes = s.iteration, s.episodes
        self.progress.start(self, resumed)
        result = TrainResult(self.folder.path, car=self.eval_world.sim.car_params.name)
        try:
            if self.before_run is not None:
                self.before_run(self)
            while not (reason := self._limit_reached(t_start, start_iteration, start_episodes)):
                entry = self.iterate(t_start)
                if entry:
                    result.history.append(entry)
                    self.progress.iteration(entry, self._eta(t_start, start_episodes, start_iteration))
            result.stopped = reason
        except KeyboardInterrupt:
            result.stopped = "interrupted (Ctrl-C); the last complete iteration is saved"
            result.interrupted = True
        finally:
            self.logs.close()
        result.iterations, result.episodes, result.env_steps = s.iteration, s.episodes, s.env_steps
        result.wall_seconds = time.perf_counter() - t_start
        result.best_checkpoint, result.best_metric = s.best_name, s.best_metric
        result.best_lap_time, result.first_lap = s.best_lap_time, s.first_lap
        result.best_lap_iteration = s.best_lap_iteration
        result.best_rule = self.cfg.evaluation.best_model_metric
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

