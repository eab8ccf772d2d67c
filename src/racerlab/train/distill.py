"""A camera model trained from a features teacher (DAgger), composed into the trainer's seams.

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

The composition (`taught_trainer`): a `Trainer` of the model's parts with the paired collection (`PairedCollection`:
the paired observation, the cars driven by `DaggerDriver`), DAgger's learner (`DaggerLearner`: the data set and
the fit) and the teacher phase before the run (`TeacherPhase`); the iteration, its health checks and rollback,
the checkpoint and the logs are the trainer's own, as for every model.
"""

from __future__ import annotations

import copy
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
from racerlab.train.health import RateSetting
from racerlab.train.loop import Trainer
from racerlab.train.parts import RunParts, trainer_parts
from racerlab.train.worlds import LocalCollection

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


class Teacher:
    """The features model a taught run learns from, loaded by the teacher phase (`load`): its greedy actions as the
    student's actions (`label`, in the student's `student_space`)."""

    def __init__(self, student_space):
        self.student_space = student_space
        self.agent = None  # a features PPO agent: `policy(features)`
        self.metadata = None

    def load(self, path: Path, features_space) -> None:
        self.agent, self.metadata = load_teacher(path, features_space)

    def label(self, features) -> np.ndarray:
        return teacher_targets(self.agent.policy(features), self.metadata.actions, self.student_space)


@dataclass
class DaggerDriver:
    """What drives the cars while round `round`'s data is collected: per step and car the teacher with probability
    `mix`, else the student's greedy action plus Gaussian `noise` (continuous actions); `record["target"]` is the
    teacher's action in the student's action space, for every step."""

    imitation: Imitation
    teacher: Teacher
    _: KW_ONLY
    noise: float
    seed: InitVar[int]
    mix: float = 1.0
    round: int = 0

    def __post_init__(self, seed: int) -> None:
        self.reseed(seed)

    def reseed(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def explore(self, obs) -> tuple[np.ndarray, dict]:
        targets = self.teacher.label(obs[TEACHER_KEY])
        actions = targets.copy()
        if self.mix < 1.0:
            student = self.imitation.greedy(obs)
            if not self.imitation.discrete and self.noise > 0:
                student = student + self.rng.normal(0.0, self.noise, student.shape)
            own = self.rng.random(len(targets)) >= self.mix
            actions[own] = student[own]
        return actions, {"target": targets}


class PairedCollection:
    """A collection (`train.seams.Collection`) whose worlds' observations are paired with the teacher's features and
    whose cars `driver` drives, the teacher's share in round k being `mix ** k`; its `state()` also keeps the
    teacher's training seconds, so a resumed run knows what the teacher had."""

    def __init__(self, inner, key: str, driver: DaggerDriver, mix: float):
        self.inner = inner
        self.key = key
        self.driver = driver
        self.mix = mix
        self.teacher_seconds = 0.0
        self._pair()

    def _pair(self):
        for w in self.inner.worlds:
            if not isinstance(w.observation, PairedObservation):
                w.observation = PairedObservation(w.observation, w.sim, self.key)

    def before_iteration(self, iteration: int) -> None:
        self.inner.before_iteration(iteration)
        self._pair()  # new generated tracks: new worlds
        self.driver.round, self.driver.mix = iteration, self.mix ** iteration

    def collect(self, agent, target_episodes: int, max_steps: int, first_episode_number: int = 0, *,
                deadline: float | None = None, tick=None, tick_s: float = 10.0):
        """The driver drives: the teacher its share, `agent` (the student the driver's imitation fits) the rest."""
        if agent is not self.driver.imitation.agent:
            raise ValueError("the paired collection's driver fits another agent than the one it was given")
        return self.inner.collect(self.driver, target_episodes, max_steps, first_episode_number=first_episode_number,
                                  deadline=deadline, tick=tick, tick_s=tick_s)

    def state(self) -> dict:
        return {**self.inner.state(), "teacher_seconds": self.teacher_seconds}

    def restore(self, saved: dict) -> None:
        self.inner.restore(saved)
        self.teacher_seconds = float((saved or {}).get("teacher_seconds", 0.0))

    def metrics(self, iteration: int) -> dict:
        return {**self.inner.metrics(iteration), "distill/round": float(self.driver.round),
                "distill/teacher_mix": self.driver.mix, "distill/teacher_seconds": self.teacher_seconds}

    def close(self) -> None:
        self.inner.close()


class DaggerLearner:
    """DAgger's learner (`train.seams.Learner`): a round's steps join the aggregated data set (`demos`), the
    current teacher labels all of it again, and the student's policy network is fitted to the labels
    (`imitation`: `passes` x the new steps / `batch_size` minibatch steps). A rollback restores the student's
    weights and the fit's optimiser and halves the fit's rate (`teacher.lr`)."""

    def __init__(self, imitation: Imitation, demos: Demonstrations, driver: DaggerDriver, settings: TeacherSettings,
                 *, source: str, note):
        self.imitation = imitation
        self.agent = imitation.agent
        self.demos = demos
        self.driver = driver
        self.settings = settings
        self.rate = RateSetting("teacher.lr", settings.lr, source, default=TeacherSettings().lr)
        self.note = note
        self.deadline: float | None = None

    @property
    def lr(self) -> float:
        return self.imitation.optimizer.param_groups[0]["lr"]

    @lr.setter
    def lr(self, value: float) -> None:
        for group in self.imitation.optimizer.param_groups:
            group["lr"] = float(value)

    def finite(self) -> bool:
        return self.agent.finite()

    def state_dict(self) -> dict:
        return {"student": self.agent.state_dict(), "fit": copy.deepcopy(self.imitation.optimizer.state_dict())}

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state["student"])
        self.imitation.optimizer.load_state_dict(copy.deepcopy(state["fit"]))

    def learn(self, rollout) -> dict:
        t0 = time.perf_counter()
        metrics = self._fit(rollout)
        d = self.driver
        self.note(f"dagger round {d.round}: teacher drives {d.mix:.0%} of steps; collect {rollout.seconds:.1f} s "
                  f"({rollout.rewards.size} steps), fit {time.perf_counter() - t0:.1f} s "
                  f"({metrics['distill/steps']:.0f} steps of {self.imitation.batch_size} on {len(self.demos)}; loss "
                  f"{metrics['distill/loss_start']:.4f} → {metrics['distill/loss_end']:.4f})")
        return metrics

    def _fit(self, ro) -> dict:
        if ro.rewards.size == 0:
            return {"distill/loss_start": math.nan, "distill/loss_end": math.nan, "distill/steps": 0.0,
                    "distill/set": float(len(self.demos)), "nonfinite": 0.0}
        keys = (*self.agent.keys, TEACHER_KEY)
        added = self.demos.add({k: ro.obs[k] for k in keys})
        targets = self.driver.teacher.label(self.demos.column(TEACHER_KEY))  # the current teacher labels all again
        s = self.settings
        steps = math.ceil(s.passes * added / s.batch_size)
        inputs = {k: self.demos.column(k) for k in self.agent.keys}
        metrics = self.imitation.fit(inputs, targets, steps, deadline=self.deadline)
        metrics["distill/set"] = float(len(self.demos))
        # a loss gone non-finite is the NaN guard's to roll back (train.health), as a PPO update's
        metrics["nonfinite"] = float(metrics["distill/steps"] > 0 and not math.isfinite(metrics["distill/loss_end"]))
        return metrics


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


@dataclass
class TeacherPhase:
    """The step before a taught run's first round (the trainer's `before_run`): create the model's own teacher if
    it has none yet, train it (its own `Trainer`, on the CPU) for what is left of teacher.iterations and
    teacher.minutes within --minutes, and load it; a teacher given for the run (`trains` False) is loaded as it
    is."""

    parts: RunParts
    path: Path
    trains: bool
    teacher: Teacher
    collection: PairedCollection

    def __call__(self, trainer: Trainer) -> None:
        s, model = self.parts.cfg.teacher, self.parts.folder
        if self.trains:
            if not ModelFolder(self.path).metadata_path.exists():
                create_teacher(model, self.parts.cfg, self.path)
                trainer.note(f"teacher: created the features model {self.path} (same track, car, actions, reward)")
            left = s.minutes * 60 - self.collection.teacher_seconds
            if trainer.deadline is not None:
                left = min(left, trainer.deadline - time.perf_counter())
            done = max((c.iteration for c in ModelFolder(self.path).checkpoints()), default=0)
            if left >= 1 and done < s.iterations:
                self._train(trainer, left, s.iterations - done)
        self.teacher.load(self.path, FeaturesObservation(trainer.eval_world.sim).space)
        self.collection.driver.reseed(self.parts.cfg.run.seed + trainer.state.iteration)

    def _train(self, trainer: Trainer, seconds: float, iterations: int) -> None:
        trainer.note(f"phase teacher: training {self.path.name}/ for {iterations} iterations, at most "
                     f"{seconds:.0f} s")
        t0 = time.perf_counter()
        r = Trainer(self.path, progress=trainer.progress.enabled, minutes=seconds / 60, iterations=iterations,
                    device="cpu").run()
        spent = time.perf_counter() - t0
        self.collection.teacher_seconds += spent
        lap = "no lap yet" if math.isnan(r.best_lap_time) else f"best lap {r.best_lap_time:.2f} s"
        trainer.note(f"phase teacher: {r.iterations} iterations in {spent:.0f} s, {lap}")


def _check_student(parts: RunParts) -> None:
    if parts.metadata.training_algorithm != "clipped_ppo" or not hasattr(parts.agent, "policy_net"):
        raise ConfigError(f"{parts.folder.metadata_path}: a teacher trains PPO students only; this model is "
                          f"{parts.metadata.training_algorithm}: set [teacher] model = \"\" in training.toml")
    if parts.worlds[0].observation.name.startswith("features"):
        raise ConfigError(f"{parts.cfg.source}: [teacher] is for camera and lidar models; a features model "
                          "learns by itself: set [teacher] model = \"\"")


def taught_trainer(model_dir, *, teacher=None, progress: bool = True, stop_at_first_lap: bool = False,
                   **overrides) -> Trainer:
    """The trainer of a model taught by a features teacher (module docstring): `teacher` is a teacher folder given
    for this run (used as it is); None takes training.toml's `[teacher] model` (the model's own, trained first)."""
    parts = trainer_parts(model_dir, overrides, progress=progress)
    _check_student(parts)
    s, seed = parts.cfg.teacher, parts.cfg.run.seed
    path = teacher_folder(parts.folder, str(teacher) if teacher is not None else s.model)
    imitation = Imitation(parts.agent, batch_size=s.batch_size, lr=s.lr, precision=s.precision, seed=seed,
                          threads=parts.cfg.run.threads)
    tutor = Teacher(parts.metadata.actions)
    driver = DaggerDriver(imitation, tutor, noise=s.noise, seed=seed)
    collection = PairedCollection(LocalCollection(parts.builder), parts.agent.keys[0], driver, s.mix)
    learner = DaggerLearner(imitation, Demonstrations(s.max_steps, seed=seed), driver, s, source=parts.cfg.source,
                            note=parts.note)
    phase = TeacherPhase(parts, path, teacher is None and s.minutes > 0, tutor, collection)
    return Trainer(parts, stop_at_first_lap=stop_at_first_lap, collector=collection, learner=learner,
                   before_run=phase)
