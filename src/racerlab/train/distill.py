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
import hashlib
import math
import shlex
import time
from dataclasses import KW_ONLY, InitVar, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from racerlab.agent.imitate import Demonstrations, Imitation, teacher_targets
from racerlab.errors import ConfigError, RacerlabError
from racerlab.model import ModelFolder
from racerlab.model.config import RandomiseSettings, RunSettings, TeacherSettings
from racerlab.model.hyperparameters import Hyperparameters
from racerlab.sim.observations import FeaturesObservation
from racerlab.train.dagger_store import DaggerStore, StoreError
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

    def load(self, path: Path, features_space, named: str = "teacher") -> None:
        self.agent, self.metadata = load_teacher(path, features_space, named)

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
    teacher's budget (its training seconds, the iteration it began at, what it is for), so a resumed run knows what
    the teacher had."""

    def __init__(self, inner, key: str, driver: DaggerDriver, mix: float):
        self.inner = inner
        self.key = key
        self.driver = driver
        self.mix = mix
        self.teacher_seconds = 0.0  # what the teacher has trained for its current budget
        self.teacher_from = 0  # the teacher's iteration its current budget began at (0, or when the model changed)
        self.teacher_for = ""  # what the teacher trains for (`trained_for`; "" before racerlab kept it)
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
        return {**self.inner.state(), "teacher_seconds": self.teacher_seconds, "teacher_from": self.teacher_from,
                "teacher_for": self.teacher_for}

    def restore(self, saved: dict) -> None:
        self.inner.restore(saved)
        saved = saved or {}
        self.teacher_seconds = float(saved.get("teacher_seconds", 0.0))
        self.teacher_from = int(saved.get("teacher_from", 0))
        self.teacher_for = str(saved.get("teacher_for", ""))

    def metrics(self, iteration: int) -> dict:
        return {**self.inner.metrics(iteration), "distill/round": float(self.driver.round),
                "distill/teacher_mix": self.driver.mix, "distill/teacher_seconds": self.teacher_seconds}

    def close(self) -> None:
        self.inner.close()


class DaggerLearner:
    """DAgger's learner (`train.seams.Learner`): a round's steps join the aggregated data set (`demos`), the
    current teacher labels all of it again, and the student's policy network is fitted to the labels
    (`imitation`: `passes` x the new steps / `batch_size` minibatch steps). A rollback restores the student's
    weights and the fit's optimiser and halves the fit's rate (`teacher.lr`). The set and the optimiser are kept
    with every checkpoint in `store` (`train.dagger_store`), so a resumed run goes on with both."""

    def __init__(self, imitation: Imitation, demos: Demonstrations, driver: DaggerDriver, settings: TeacherSettings,
                 *, store: DaggerStore, source: str, note):
        self.imitation = imitation
        self.agent = imitation.agent
        self.demos = demos
        self.driver = driver
        self.settings = settings
        self.store = store
        self.pending: list[np.ndarray] = []  # the set's rows written since the store's last file
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
        self.pending.append(self.demos.last_rows.copy())
        targets = self.driver.teacher.label(self.demos.column(TEACHER_KEY))  # the current teacher labels all again
        s = self.settings
        steps = math.ceil(s.passes * added / s.batch_size)
        inputs = {k: self.demos.column(k) for k in self.agent.keys}
        metrics = self.imitation.fit(inputs, targets, steps, deadline=self.deadline)
        metrics["distill/set"] = float(len(self.demos))
        # a loss gone non-finite is the NaN guard's to roll back (train.health), as a PPO update's
        metrics["nonfinite"] = float(metrics["distill/steps"] > 0 and not math.isfinite(metrics["distill/loss_end"]))
        return metrics

    # ---- kept with the checkpoints -------------------------------------------------------------------------
    def keep(self, iteration: int) -> None:
        d = self.demos
        if not d.columns:
            return  # no step collected yet
        rows = np.concatenate(self.pending) if self.pending else np.empty(0, dtype=np.int64)
        fit, fit_meta = self._fit_state()
        self.store.save(iteration, d.columns, d.size, rows, {"seen": d.seen, "rng": d.rng.bit_generator.state},
                        fit, fit_meta)
        self.pending = []

    def resume(self, iteration: int) -> None:
        try:
            loaded = self.store.load(iteration)
            if loaded is not None:
                self._take_set(loaded)
        except StoreError as exc:
            self.store.clear()
            self.demos.columns, self.demos.size, self.demos.seen = {}, 0, 0
            self.note(f"{exc}; DAgger's data set starts empty (the coming rounds' steps fill it)")
            return
        if loaded is None:
            return
        fit = self._take_fit(loaded)
        self.note(f"dagger: resumed with {len(self.demos)} labelled steps ({loaded.seen} collected in all) and "
                  f"{fit} ({self.store.path})")

    def _take_set(self, loaded) -> None:
        d = self.demos
        if loaded.capacity == d.capacity:
            d.columns, d.size = loaded.columns, loaded.size
        else:
            n = min(loaded.size, d.capacity)
            d.add({k: v[:n] for k, v in loaded.columns.items()})
            self.note(f"teacher.max_steps is {d.capacity} and the data set had room for {loaded.capacity}: it goes "
                      f"on with {n} of its {loaded.size} steps")
        d.seen = int(loaded.seen)
        try:
            d.rng.bit_generator.state = loaded.rng
        except (TypeError, ValueError, KeyError) as exc:
            raise StoreError(f"{self.store.path}: the data set's random state is not one ({exc})") from None

    def _fit_state(self) -> tuple[dict[str, np.ndarray], dict]:
        """The fit's optimiser (its tensors by parameter, its groups) and minibatch generator, as arrays and JSON."""
        sd = self.imitation.optimizer.state_dict()
        arrays = {f"s.{i}.{k}": (v.detach().cpu().numpy() if torch.is_tensor(v) else np.asarray(v))
                  for i, st in sd["state"].items() for k, v in st.items()}
        arrays["generator"] = self.imitation.generator.get_state().numpy()
        return arrays, {"param_groups": sd["param_groups"], "rate": self.settings.lr}

    def _take_fit(self, loaded) -> str:
        """Load the kept optimiser into the fit; says what the run goes on with."""
        opt, meta = self.imitation.optimizer, loaded.fit_meta
        params = [p for group in opt.param_groups for p in group["params"]]
        state: dict[int, dict] = {}
        try:
            for name, value in loaded.fit.items():
                if name != "generator":
                    _, i, key = name.split(".", 2)
                    state.setdefault(int(i), {})[key] = torch.from_numpy(np.array(value))
            if any(i >= len(params) or st["exp_avg"].shape != params[i].shape for i, st in state.items()):
                raise ValueError("its moments do not fit the student's policy network")
            groups = [{**g, "betas": tuple(g["betas"])} for g in meta["param_groups"]]
            opt.load_state_dict({"state": state, "param_groups": groups})
            self.imitation.generator.set_state(torch.from_numpy(np.array(loaded.fit["generator"])))
        except (KeyError, ValueError, TypeError, RuntimeError) as exc:
            self.imitation.optimizer = torch.optim.Adam(self.imitation.policy.parameters(), lr=self.settings.lr,
                                                        eps=1e-5)
            return f"a fresh optimiser for the fit (the kept one does not load: {exc})"
        if meta.get("rate") != self.settings.lr:  # an edited teacher.lr takes effect, as an edited lr does for PPO
            self.lr = self.settings.lr
            return f"the fit's optimiser, at the edited teacher.lr {self.settings.lr:g} (was {meta.get('rate')!r})"
        return f"the fit's optimiser (rate {self.lr:g})"


def teacher_folder(model: ModelFolder, name: str) -> Path:
    """training.toml's `[teacher] model`: relative to the model folder (a teacher given with --teacher is a path as
    any other flag's: relative to the current folder)."""
    path = Path(name).expanduser()
    return path if path.is_absolute() else model.path / path


def _teacher_header(model: ModelFolder) -> str:
    return f"# the features teacher of {model.path.name} (racerlab.train.distill)\n"


def create_teacher(model: ModelFolder, cfg, path: Path) -> ModelFolder:
    """A features model beside the student: the same actions, tracks (all of them at once), car, start rules and
    reward, AWS-default hyperparameters with an episode per car in each iteration, the best checkpoint picked by lap
    time, no teacher and no randomisation of its own."""
    teacher = ModelFolder(path)
    meta = model.metadata()
    teacher.write_metadata(replace(meta, sensor=("FEATURES",), neural_network="MLP", training_algorithm="clipped_ppo",
                                   lidar_config={}))
    # a features step is cheap: the default 32 cars at least, and every named track at once (no `at_once`)
    cars = max(cfg.run.num_cars, RunSettings().num_cars, 0 if cfg.track.generated else len(cfg.track.names))
    hp = Hyperparameters()
    # an iteration starts one episode per car at most as many as it collects: each car (and track) drives in each
    teacher.write_hyperparameters(hp.replace(num_episodes_between_training=max(hp.num_episodes_between_training,
                                                                               cars)))
    teacher.write_reward(model.reward_path.read_text(encoding="utf-8"))
    tcfg = replace(cfg, teacher=TeacherSettings(), randomise=RandomiseSettings(), workers=(),
                   track=replace(cfg.track, at_once=0),
                   run=replace(cfg.run, observation="", threads=0, num_cars=cars),
                   evaluation=replace(cfg.evaluation, best_model_metric="laptime"),
                   stop=replace(cfg.stop, minutes=0.0, episodes=0, iterations=0))
    teacher.write_config(tcfg, header=_teacher_header(model))
    return teacher


def differences(model: ModelFolder, cfg, teacher: ModelFolder) -> list[str]:
    """What the teacher trains with that is not the model's own: its reward function, its car ([car])."""
    out = []
    reward = teacher.reward_path.read_text(encoding="utf-8") if teacher.reward_path.is_file() else None
    if reward != model.reward_path.read_text(encoding="utf-8"):
        out.append(model.reward_path.name)
    if teacher.config().car != cfg.car:
        out.append("[car]")
    return out


def follow_model(model: ModelFolder, cfg, teacher: ModelFolder) -> list[str]:
    """The model's own teacher takes the model's current reward and car (`differences`); returns what it took."""
    changed = differences(model, cfg, teacher)
    if model.reward_path.name in changed:
        teacher.write_reward(model.reward_path.read_text(encoding="utf-8"))
    if "[car]" in changed:
        teacher.write_config(replace(teacher.config(), car=cfg.car), header=_teacher_header(model))
    return changed


def trained_for(model: ModelFolder, cfg) -> str:
    """A fingerprint of what a teacher trains for: the model's reward function and car."""
    text = model.reward_path.read_text(encoding="utf-8") + "\0" + repr(cfg.car)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def check_teacher(path: Path, named: str) -> ModelFolder:
    """A teacher that is not the model's own to create: a trained features PPO model, or one line that names it
    (`named`: the flag or training.toml's key) and the fix."""
    folder = ModelFolder(path)
    q = shlex.quote(str(path))
    if not folder.metadata_path.is_file():
        raise RacerlabError(f"{named}: {path} is not a model folder; a teacher is a trained features model: make one "
                            f"with `racerlab init {q} --sensor features` and `racerlab train {q} --minutes 2`")
    meta = folder.metadata()
    if tuple(meta.sensor) != ("FEATURES",) or meta.training_algorithm != "clipped_ppo":
        raise ConfigError(f"{folder.metadata_path}: a teacher must be a features PPO model (sensor FEATURES, "
                          f"clipped_ppo), this one has sensor {list(meta.sensor)} and {meta.training_algorithm}")
    if not folder.checkpoints():
        raise RacerlabError(f"{named}: the teacher {path} has no checkpoint; train it first "
                            f"(`racerlab train {q} --minutes 2`)")
    return folder


def load_teacher(path: Path, features_space, named: str = "teacher"):
    """The teacher's agent (its best checkpoint, on the CPU: a small vector network) and its metadata."""
    from racerlab.agent import make_agent

    opened = check_teacher(path, named).open("best")  # the door: unreadable, non-finite, mismatched: one line
    agent = make_agent(features_space, opened.metadata, opened.hyperparameters, device="cpu")
    agent.load_state_dict(opened.state.agent)
    return agent, opened.metadata


@dataclass
class TeacherPhase:
    """The step before a taught run's first round (the trainer's `before_run`): the model's own teacher (`trains`)
    is created if it has none yet, takes the model's current reward and car (and trains anew for them when they
    changed since it trained), and trains (its own `Trainer`, on the CPU) for what is left of teacher.iterations
    and teacher.minutes within --minutes; then the teacher is loaded. A teacher given for the run is used as it is
    (the run says so when its reward or car is not the model's). Ctrl-C while the teacher trains stops the run."""

    parts: RunParts
    path: Path
    trains: bool
    named: str  # how the user named the teacher (the flag, or training.toml's key), for its errors
    teacher: Teacher
    collection: PairedCollection

    def __call__(self, trainer: Trainer) -> None:
        s = self.parts.cfg.teacher
        if self.trains:
            if not ModelFolder(self.path).metadata_path.exists():
                create_teacher(self.parts.folder, self.parts.cfg, self.path)
                trainer.note(f"teacher: created the features model {self.path} (same track, car, actions, reward)")
            done = max((c.iteration for c in ModelFolder(self.path).checkpoints()), default=0)
            self._follow(trainer, done)
            c = self.collection
            left = s.minutes * 60 - c.teacher_seconds
            if trainer.deadline is not None:
                left = min(left, trainer.deadline - time.perf_counter())
            if left >= 1 and done - c.teacher_from < s.iterations:
                self._train(trainer, left, s.iterations - (done - c.teacher_from))
        else:
            self._say_apart(trainer)
        self.teacher.load(self.path, FeaturesObservation(trainer.eval_world.sim).space, self.named)
        self.collection.driver.reseed(self.parts.cfg.run.seed + trainer.state.iteration)

    def _follow(self, trainer: Trainer, done: int) -> None:
        """The own teacher follows the model: what changed is written into its folder, and a teacher trained for
        another reward or car gets a whole teacher budget again (from its `done` iterations)."""
        model, cfg, c = self.parts.folder, self.parts.cfg, self.collection
        changed = follow_model(model, cfg, ModelFolder(self.path))
        now = trained_for(model, cfg)
        # a run stopped after the files were taken but before its next checkpoint still has the old fingerprint
        if changed or c.teacher_for not in ("", now):
            c.teacher_seconds, c.teacher_from = 0.0, done
            what = " and ".join(changed) or "reward function and car"
            trainer.note(f"teacher: {self.path.name}/ takes the model's {what} (changed since it trained) and trains "
                         f"again: {self.parts.cfg.teacher.iterations} iterations or "
                         f"{self.parts.cfg.teacher.minutes:g} min")
        c.teacher_for = now

    def _say_apart(self, trainer: Trainer) -> None:
        teacher = ModelFolder(self.path)
        if not teacher.metadata_path.is_file():
            return  # check_teacher says what is wrong
        apart = differences(self.parts.folder, self.parts.cfg, teacher)
        if apart:
            trainer.note(f"teacher: {self.path} is used as it is, trained with its own {' and '.join(apart)}, not "
                         f"this model's: its actions follow them")

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
        if r.interrupted:  # Ctrl-C stops the whole run, not the teacher alone (`train && evaluate` must stop)
            raise KeyboardInterrupt


def _check_student(parts: RunParts) -> None:
    if parts.metadata.training_algorithm != "clipped_ppo" or not hasattr(parts.agent, "policy_net"):
        raise ConfigError(f"{parts.folder.metadata_path}: a teacher trains PPO students only; this model is "
                          f"{parts.metadata.training_algorithm}: set [teacher] model = \"\" in training.toml")
    if parts.worlds[0].observation.name.startswith("features"):
        raise ConfigError(f"{parts.cfg.source}: [teacher] is for camera and lidar models; a features model "
                          "learns by itself: set [teacher] model = \"\"")


def _columns(parts: RunParts) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """The data set's columns: the student's inputs and the teacher's features, each a row shape and type."""
    space, keys = parts.worlds[0].observation.space, parts.agent.keys
    spaces = dict(space.spaces) if hasattr(space, "spaces") else {keys[0]: space}
    features = FeaturesObservation(parts.worlds[0].sim).space
    return {**{k: (tuple(spaces[k].shape), np.dtype(spaces[k].dtype)) for k in keys},
            TEACHER_KEY: (tuple(features.shape), np.dtype(features.dtype))}


def _learner(parts: RunParts, imitation: Imitation, driver: DaggerDriver) -> DaggerLearner:
    s, seed = parts.cfg.teacher, parts.cfg.run.seed
    fit_bytes = 3 * sum(p.numel() * p.element_size() for p in imitation.policy.parameters())  # moments and weights
    store = DaggerStore(parts.folder.dagger_dir, _columns(parts), s.max_steps, fit_bytes)
    return DaggerLearner(imitation, Demonstrations(s.max_steps, seed=seed), driver, s, store=store,
                         source=parts.cfg.source, note=parts.note)


def taught_trainer(model_dir, *, teacher=None, progress: bool = True, stop_at_first_lap: bool = False,
                   **overrides) -> Trainer:
    """The trainer of a model taught by a features teacher (module docstring): `teacher` is a teacher folder given
    for this run (a path as any other flag's; used as it is); None takes training.toml's `[teacher] model` (the
    model's own, relative to its folder, trained first)."""
    if teacher is not None:
        check_teacher(Path(teacher).expanduser(), f"--teacher {teacher}")  # before the student's worlds are built
    parts = trainer_parts(model_dir, overrides, progress=progress)
    _check_student(parts)
    s, seed = parts.cfg.teacher, parts.cfg.run.seed
    if teacher is not None:
        path, named, trains = Path(teacher).expanduser(), f"--teacher {teacher}", False
    else:
        path, named, trains = teacher_folder(parts.folder, s.model), f"{parts.cfg.source}: teacher.model", s.minutes > 0
    imitation = Imitation(parts.agent, batch_size=s.batch_size, lr=s.lr, precision=s.precision, seed=seed,
                          threads=parts.cfg.run.threads)
    tutor = Teacher(parts.metadata.actions)
    driver = DaggerDriver(imitation, tutor, noise=s.noise, seed=seed)
    collection = PairedCollection(LocalCollection(parts.builder), parts.agent.keys[0], driver, s.mix)
    phase = TeacherPhase(parts, path, trains, named, tutor, collection)
    return Trainer(parts, stop_at_first_lap=stop_at_first_lap, collector=collection,
                   learner=_learner(parts, imitation, driver), before_run=phase)
