"""A camera model trained from a features teacher (DAgger), in the trainer's iterations.

The method (docs/learner.md, "A camera model from a features teacher"):
1. **Teacher.** A `features` model learns the track by PPO in a minute or two (it sees the car's speed, offset,
   heading and the centre line ahead: a small vector and a small network). A model's own teacher lives in its
   folder (`[teacher] model = "teacher"`, created on first use with the same track, car, actions and reward) and
   trains `teacher.iterations` iterations or `teacher.minutes`, whichever ends first, before the first round (a
   resumed run: what is left of them). A teacher given with `racerlab train --teacher DIR` is used as it is.
2. **DAgger rounds**, one per iteration. The cars drive whole episodes as usual, but each step is driven by the
   teacher with probability `mix ** k` in round k and otherwise by the student (its greedy action plus
   `noise`); every step is labelled with the teacher's greedy action computed from the features vector of the
   same car (`PairedObservation` renders the camera frame and computes the vector for the same poses). The
   steps join the aggregated data set (`agent.imitate.Demonstrations`), all of it is labelled again by the
   current teacher, and the student's policy network is fitted to it (`agent.imitate.Imitation`:
   `passes x new steps` rows of minibatches); the greedy evaluation, checkpoint, logs and metrics line follow as
   in every training.
The student is the model's own network (the AWS camera network), so the checkpoints are plain PPO checkpoints:
evaluation, export, clone and a later `racerlab train` without a teacher (PPO from there) read them as any other.
"""

from __future__ import annotations

import math
import time
from dataclasses import KW_ONLY, InitVar, dataclass, replace
from pathlib import Path

import numpy as np

from racerlab.agent.imitate import Demonstrations, Imitation, teacher_targets
from racerlab.errors import ConfigError, RacerlabError
from racerlab.model import ModelFolder
from racerlab.model.config import RandomiseSettings, RunSettings, TeacherSettings
from racerlab.model.hyperparameters import Hyperparameters
from racerlab.sim.observations import FeaturesObservation
from racerlab.train.loop import Trainer, _ctrl_c_after

TEACHER_KEY = "teacher:features"  # the teacher's input in a paired observation (no network input has this name)


class PairedObservation:
    """A world's own observation and the features vector of the same cars, as one dict (the student's input
    under its network's name, `key`, or the inputs of a combined sensor; the vector under TEACHER_KEY)."""

    partial_update = True

    def __init__(self, own, sim, key: str):
        self.own = own
        self.key = key
        self.features = FeaturesObservation(sim)
        self.name = getattr(own, "name", key)

    @property
    def space(self):
        return self.own.space

    def __call__(self, rows=None) -> dict:
        partial = rows is not None
        own = self.own(rows) if partial and getattr(self.own, "partial_update", False) else self.own()
        out = dict(own) if isinstance(own, dict) else {self.key: own}
        out[TEACHER_KEY] = self.features(rows) if partial else self.features()
        return out


class PairedCollection:
    """The trainer's local collection with every world's observation paired with the teacher's features; its
    `state()` also keeps the teacher's training seconds, so a resumed run knows what the teacher had."""

    def __init__(self, inner, key: str):
        self.inner = inner
        self.key = key
        self.teacher_seconds = 0.0
        self._pair()

    def _pair(self):
        for w in self.inner.worlds:
            if not isinstance(w.observation, PairedObservation):
                w.observation = PairedObservation(w.observation, w.sim, self.key)

    def before_iteration(self, iteration: int) -> None:
        self.inner.before_iteration(iteration)
        self._pair()  # new generated tracks: new worlds

    def collect(self, agent, target_episodes: int, max_steps: int, first_episode_number: int = 0, *,
                deadline: float | None = None, tick=None, tick_s: float = 10.0):
        return self.inner.collect(agent, target_episodes, max_steps, first_episode_number=first_episode_number,
                                  deadline=deadline, tick=tick, tick_s=tick_s)

    def state(self) -> dict:
        return {**self.inner.state(), "teacher_seconds": self.teacher_seconds}

    def restore(self, saved: dict) -> None:
        self.inner.restore(saved)
        self.teacher_seconds = float((saved or {}).get("teacher_seconds", 0.0))

    def metrics(self, iteration: int) -> dict:
        return self.inner.metrics(iteration)

    def close(self) -> None:
        self.inner.close()


@dataclass
class DaggerDriver:
    """What drives the cars while a round's data is collected (the collector's `agent`): per step and car the
    teacher with probability `mix`, else the student's greedy action plus Gaussian `noise` (continuous actions);
    `record["target"]` is the teacher's action in the student's action space, for every step."""

    imitation: Imitation
    teacher: object  # a features agent: `policy(features)`
    teacher_space: object
    student_space: object
    _: KW_ONLY
    noise: float
    seed: InitVar[int]
    mix: float = 1.0

    def __post_init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def label(self, features) -> np.ndarray:
        return teacher_targets(self.teacher.policy(features), self.teacher_space, self.student_space)

    def explore(self, obs) -> tuple[np.ndarray, dict]:
        targets = self.label(obs[TEACHER_KEY])
        actions = targets.copy()
        if self.mix < 1.0:
            student = self.imitation.greedy(obs)
            if not self.imitation.discrete and self.noise > 0:
                student = student + self.rng.normal(0.0, self.noise, student.shape)
            own = self.rng.random(len(targets)) >= self.mix
            actions[own] = student[own]
        return actions, {"target": targets}


def teacher_folder(model: ModelFolder, name: str) -> Path:
    path = Path(name).expanduser()
    return path if path.is_absolute() else model.path / path


def create_teacher(model: ModelFolder, cfg, path: Path) -> ModelFolder:
    """A features model beside the student: the same actions, track, car, start rules and reward, AWS-default
    hyperparameters, the best checkpoint picked by lap time, no teacher and no randomisation of its own."""
    teacher = ModelFolder(path)
    meta = model.metadata()
    teacher.write_metadata(replace(meta, sensor=("FEATURES",), neural_network="MLP", training_algorithm="clipped_ppo",
                                   lidar_config={}))
    teacher.write_hyperparameters(Hyperparameters())
    teacher.write_reward(model.reward_path.read_text(encoding="utf-8"))
    cars = max(cfg.run.num_cars, RunSettings().num_cars)  # a features step is cheap: the default 32 cars at least
    tcfg = replace(cfg, teacher=TeacherSettings(), randomise=RandomiseSettings(), workers=(),
                   run=replace(cfg.run, observation="", threads=0, num_cars=cars),
                   evaluation=replace(cfg.evaluation, best_model_metric="laptime"),
                   stop=replace(cfg.stop, minutes=0.0, episodes=0, iterations=0))
    teacher.write_config(tcfg, header=f"# the features teacher of {model.path.name} (racerlab.train.distill)\n")
    return teacher


def load_teacher(path: Path, features_space):
    """The teacher's agent (its best checkpoint, on the CPU: a small vector network) and its metadata."""
    from racerlab.agent import make_agent

    folder = ModelFolder(path)
    folder.require()
    meta = folder.metadata()
    if tuple(meta.sensor) != ("FEATURES",) or meta.training_algorithm != "clipped_ppo":
        raise ConfigError(f"{folder.metadata_path}: a teacher must be a features PPO model (sensor FEATURES, "
                          f"clipped_ppo), this one has sensor {list(meta.sensor)} and {meta.training_algorithm}")
    if not folder.checkpoints():
        raise RacerlabError(f"{folder.path}: the teacher has no checkpoint; train it first "
                            f"(`racerlab train {folder.path} --minutes 2`)")
    state = folder.load_state(folder.resolve_checkpoint("best"))
    agent = make_agent(features_space, meta, folder.hyperparameters(), device="cpu")
    agent.load_state_dict(state.agent)
    return agent, meta


class DistillTrainer(Trainer):
    """`Trainer` whose iterations are DAgger rounds from a features teacher (module docstring). `teacher`: a
    teacher folder given for this run (used as it is); None takes training.toml's `[teacher] model`."""

    def __init__(self, model_dir, progress: bool = True, stop_at_first_lap: bool = False, *, teacher=None,
                 **overrides):
        super().__init__(model_dir, progress, stop_at_first_lap, **overrides)
        self.settings: TeacherSettings = self.cfg.teacher
        if self.metadata.training_algorithm != "clipped_ppo" or not hasattr(self.agent, "policy_net"):
            raise ConfigError(f"{self.folder.metadata_path}: a teacher trains PPO students only; this model is "
                              f"{self.metadata.training_algorithm}: set [teacher] model = \"\" in training.toml")
        if self.eval_world.observation.name.startswith("features"):
            raise ConfigError(f"{self.cfg.source}: [teacher] is for camera and lidar models; a features model "
                              "learns by itself: set [teacher] model = \"\"")
        name = str(teacher) if teacher is not None else self.settings.model
        self.teacher_path = teacher_folder(self.folder, name)
        self.trains_teacher = teacher is None and self.settings.minutes > 0
        self.collector = PairedCollection(self.collector, self.agent.keys[0])
        s = self.settings
        self.imitation = Imitation(self.agent, batch_size=s.batch_size, lr=s.lr, precision=s.precision,
                                   seed=self.cfg.run.seed, threads=self.cfg.run.threads)
        self.demos = Demonstrations(s.max_steps, seed=self.cfg.run.seed)
        self.features_space = FeaturesObservation(self.eval_world.sim).space
        self.teacher = self.teacher_meta = self.driver = None

    # ---- the teacher ---------------------------------------------------------------------------
    def _teach(self) -> None:
        """Before the run's first round: create the model's own teacher if it has none yet, train it for what is
        left of teacher.iterations and teacher.minutes (within --minutes), and load it."""
        if self.teacher is not None:
            return
        if self.trains_teacher:
            if not ModelFolder(self.teacher_path).metadata_path.exists():
                create_teacher(self.folder, self.cfg, self.teacher_path)
                self.note(f"teacher: created the features model {self.teacher_path} (same track, car, actions, "
                          "reward)")
            left = self.settings.minutes * 60 - self.collector.teacher_seconds
            if self.deadline is not None:
                left = min(left, self.deadline - time.perf_counter())
            done = max((c.iteration for c in ModelFolder(self.teacher_path).checkpoints()), default=0)
            if left >= 1 and done < self.settings.iterations:
                self._train_teacher(left, self.settings.iterations - done)
        self.teacher, self.teacher_meta = load_teacher(self.teacher_path, self.features_space)
        self.driver = DaggerDriver(self.imitation, self.teacher, self.teacher_meta.actions, self.metadata.actions,
                                   noise=self.settings.noise, seed=self.cfg.run.seed + self.state.iteration)

    def _train_teacher(self, seconds: float, iterations: int) -> None:
        from racerlab.train.loop import train

        self.note(f"phase teacher: training {self.teacher_path.name}/ for {iterations} iterations, at most "
                  f"{seconds:.0f} s")
        t0 = time.perf_counter()
        r = train(self.teacher_path, minutes=seconds / 60, iterations=iterations, progress=self.progress.enabled,
                  device="cpu")
        spent = time.perf_counter() - t0
        self.collector.teacher_seconds += spent
        lap = "no lap yet" if math.isnan(r.best_lap_time) else f"best lap {r.best_lap_time:.2f} s"
        self.note(f"phase teacher: {r.iterations} iterations in {spent:.0f} s, {lap}")

    # ---- one round -----------------------------------------------------------------------------
    def iterate(self, t_start: float) -> dict:
        s = self.state
        round_k = s.iteration
        self._teach()
        if self.deadline is not None and time.perf_counter() >= self.deadline:
            return {}
        self.collector.before_iteration(round_k)
        self.driver.mix = self.settings.mix ** round_k
        target = max(self.hp.num_episodes_between_training, self.cfg.run.num_cars)
        ro = self.collector.collect(self.driver, target, self.cfg.run.max_steps_per_iteration,
                                    first_episode_number=s.episodes, deadline=self.deadline, tick=self.progress.tick)
        if ro.cut and not ro.episodes:
            s.env_steps += ro.env_steps
            return {}
        t_fit = time.perf_counter()
        with self.progress.heartbeat(f"dagger round {round_k}: fitting the student"):
            metrics = self._fit(ro)
        fit_s = time.perf_counter() - t_fit
        s.env_steps += ro.env_steps
        past = self.deadline is not None and time.perf_counter() >= self.deadline
        t_eval = time.perf_counter()
        with self.progress.heartbeat("evaluation episodes"):
            evals = [] if ro.cut or past else self._evaluate()
        eval_s = time.perf_counter() - t_eval
        self.note(f"dagger round {round_k}: teacher drives {self.driver.mix:.0%} of steps; collect {ro.seconds:.1f} s "
                  f"({ro.rewards.size} steps), fit {fit_s:.1f} s ({metrics['distill/steps']:.0f} steps of "
                  f"{self.imitation.batch_size} on {len(self.demos)}; loss {metrics['distill/loss_start']:.4f} → "
                  f"{metrics['distill/loss_end']:.4f}), evaluate {eval_s:.1f} s")
        metrics.update({"distill/round": float(round_k), "distill/teacher_mix": self.driver.mix,
                        "distill/teacher_seconds": self.collector.teacher_seconds, "distill/eval_seconds": eval_s})
        with _ctrl_c_after():
            return self._commit(ro, evals, metrics, fit_s, t_start)

    def _fit(self, ro) -> dict:
        if ro.rewards.size == 0:
            return {"distill/loss_start": math.nan, "distill/loss_end": math.nan, "distill/steps": 0.0,
                    "distill/set": float(len(self.demos))}
        keys = (*self.agent.keys, TEACHER_KEY)
        added = self.demos.add({k: ro.obs[k] for k in keys})
        targets = self.driver.label(self.demos.column(TEACHER_KEY))  # the current teacher labels every step again
        s = self.settings
        steps = math.ceil(s.passes * added / s.batch_size)
        inputs = {k: self.demos.column(k) for k in self.agent.keys}
        metrics = self.imitation.fit(inputs, targets, steps, deadline=self.deadline)
        metrics["distill/set"] = float(len(self.demos))
        return metrics
