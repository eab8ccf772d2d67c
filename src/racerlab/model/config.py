"""`training.toml`: racerlab's run settings for a model folder (what DRfC keeps in run.env).

Sections and defaults live in `DEFAULTS`; unknown sections or keys and wrong types are a
`ConfigError` naming the file and the key. Command-line flags override the file.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from racerlab.errors import ConfigError
from racerlab.logs.metrics import BEST_MODEL_METRICS
from racerlab.model.metadata import OBSERVATION_NAMES, split_observation_name
from racerlab.spec import CAR_KEYS, DEFAULT_SIMULATOR, SIMULATORS, CarParams, RaceConfig, car_params, implausible

REWARD_ORDERS = ("aws", "after_action")
PRECISIONS = ("auto", "float32", "bfloat16")  # teacher.precision: the student's fit (racerlab.agent.imitate)
LOOKS = ("aws", "classic")  # run.look: the camera's world, named only here (sim.sensors.look.LOOKS holds each)


@dataclass(frozen=True)
class TrackSettings:
    names: tuple[str, ...] = ("lab_technical",)  # several tracks: the cars are spread over them
    reverse: bool = False  # REVERSE_DIR
    alternate_direction: bool = False  # ALTERNATE_DRIVING_DIRECTION
    change_start: bool = True  # CHANGE_START_POSITION
    round_robin_advance: float = 0.05  # ROUND_ROBIN_ADVANCE_DIST
    start_offset: float = 0.0  # START_POSITION_OFFSET
    # generated tracks (racerlab.track.generate): with generated = N > 0 the training cars are spread over N
    # random circuits instead of `names` (which then only hold the in-training evaluation track), drawn anew
    # every `regenerate_every` iterations (0 = keep the first draw); lengths, widths and the tightest bend
    # radius are drawn from the ranges below (AWS tracks: 17-90 m long, 0.72-1.45 m wide, bends down to 0.45 m)
    generated: int = 0
    regenerate_every: int = 5
    generated_min_length: float = 20.0
    generated_max_length: float = 60.0
    generated_min_width: float = 0.76
    generated_max_width: float = 1.07
    generated_min_radius: float = 0.5
    # named tracks a few at a time: with at_once = K > 0 and more names than K, the training cars drive K of the
    # names at once (draw d: names[(d K + j) mod N], j < K, every name in turn), the next K every regenerate_every
    # iterations; worlds of camera models cost memory and seconds to build (a camera world's raster ~170 MB, ~5 s)
    at_once: int = 0

    @property
    def rotates(self) -> bool:
        """True when the named tracks are driven `at_once` at a time (fewer than there are names)."""
        return not self.generated and 0 < self.at_once < len(self.names)

    @property
    def driven(self) -> int:
        """How many named tracks the training cars drive at once."""
        return self.at_once if self.rotates else len(self.names)

    def names_of_draw(self, draw: int) -> tuple[str, ...]:
        """The named tracks of draw `draw`: all of them, or K = `at_once` in turn (names[(draw K + j) mod N])."""
        if not self.rotates:
            return self.names
        n, k = len(self.names), self.at_once
        return tuple(self.names[(draw * k + j) % n] for j in range(k))


@dataclass(frozen=True)
class RunSettings:
    num_cars: int = 32  # cars simulated in parallel (DRfC: workers)
    seed: int = 0
    device: str = "auto"  # auto | cpu | cuda | cuda:N
    threads: int = 0  # torch CPU threads; 0 = auto (agent.common.learner_threads)
    observation: str = ""  # "" follows model_metadata.json's sensor list
    look: str = "aws"  # how the world looks to a camera: aws (the AWS simulator's) | classic (racerlab's earlier)
    reward_order: str = "aws"  # aws | after_action (see racerlab.sim)
    max_steps_per_iteration: int = 10_000  # AWS MAX_MEMORY_STEPS: whole episodes beyond it are dropped
    max_episode_steps: int = 10_000
    reward_budget_s: float = 3.0  # a reward call longer than this stops training (0 = no limit)


@dataclass(frozen=True)
class StopSettings:
    minutes: float = 0.0  # 0 = no limit
    episodes: int = 0  # training episodes in total; 0 = hyperparameters' term_cond_max_episodes
    iterations: int = 0  # 0 = no limit


@dataclass(frozen=True)
class EvaluationSettings:
    episodes: int = 5  # MIN_EVAL_TRIALS greedy episodes after each iteration
    best_model_metric: str = "progress"  # BEST_MODEL_METRIC: progress | reward | laptime


@dataclass(frozen=True)
class LogSettings:
    simtrace_every: int = 1  # write the training simtrace of every k-th episode (bounds disk use)
    compress: bool = False  # gzip even the newest simtrace CSVs (deepracer-utils then reads none of them)
    plain_iterations: int = 10  # the newest iterations kept as plain CSV (deepracer-utils); older ones are gzipped
    max_mb: float = 500.0  # training-simtrace/ + metrics/ budget: past it the oldest gzipped iterations are thinned


@dataclass(frozen=True)
class RandomiseSettings:
    """Domain randomisation for the physical car (docs/learner.md). Every option is off at its default.

    Per episode (drawn for each car when its episode starts): blur, exposure, gamma, camera pose and
    the steering / throttle gains; per frame: camera noise and lidar noise; `lighting` turns on the
    camera's per-episode look randomisation (light colour, brightness, tone curve, gradient: the
    `camera:dr` option). `speed_scale` and `top_speed` map speeds as the car does: relative to the
    action space's top speed, not in m/s.
    """

    camera_noise: float = 0.0  # standard deviation of per-pixel Gaussian noise, grey levels, fresh every frame
    blur: float = 0.0  # Gaussian blur of sigma drawn from [0, blur] pixels per episode
    exposure: float = 0.0  # image gain drawn from [1 - exposure, 1 + exposure] per episode
    gamma: float = 0.0  # tone exponent drawn from [1 - gamma, 1 + gamma] per episode
    lighting: bool = False  # per-episode light colour, brightness, contrast and gradient (camera:dr)
    pose_yaw_deg: float = 0.0  # camera yaw offset drawn from [-a, a] degrees per episode
    pose_pitch_deg: float = 0.0  # camera pitch offset drawn from [-a, a] degrees per episode
    pose_shift_m: float = 0.0  # sideways camera offset drawn from [-d, d] metres per episode
    lidar_noise_m: float = 0.0  # extra Gaussian noise on every lidar range, metres, fresh every scan
    latency_steps: int = 0  # the action chosen at step t is applied at step t + latency_steps (0, 1 or 2)
    latency_varies: bool = False  # each episode draws its latency from 0..latency_steps instead (uniform)
    steering_gain: float = 0.0  # steering multiplied by a gain drawn from [1 - g, 1 + g] per episode
    throttle_gain: float = 0.0  # speed multiplied by a gain drawn from [1 - g, 1 + g] per episode
    speed_scale: float = 1.0  # the car's max-speed setting: applied speed = speed / action top x top_speed x scale
    top_speed: float = 0.0  # m/s the action space's top speed stands for (0 = the action space's own top)
    evaluation: bool = False  # also randomise the greedy evaluation episodes after each training iteration

    @property
    def active(self) -> bool:
        """True when any option differs from its default (the plain, fastest path otherwise)."""
        return any(k != "evaluation" for k in self.changed())

    def changed(self) -> dict:
        """The options that differ from their defaults, by name."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) != f.default}


@dataclass(frozen=True)
class CarSettings:
    """[car]: the simulator whose car racerlab drives (`spec.SIMULATORS`; the model's version picks the car
    within it) and any of its constants overridden (`spec.CarParams`' names, e.g. the output of `racerlab
    calibrate`)."""

    simulator: str = DEFAULT_SIMULATOR
    overrides: tuple[tuple[str, object], ...] = ()

    def table(self) -> dict:
        return {"simulator": self.simulator, **dict(self.overrides)}

    def params(self, version="5", training: bool = True) -> CarParams:
        """The car for a model of `version`. Its steps jitter as the simulator's in training (evaluations drive
        exact 1/15 s steps, so that they repeat); `step_jitter` in the table decides for both. `randomise`
        (randomised dynamics: each episode's constants drawn from the fit's spread) acts in training only:
        evaluations drive the fitted car."""
        table = {"step_jitter": training, **dict(self.overrides)}
        if not training:
            table["randomise"] = 0.0
        return car_params(self.simulator, version, **table)

    @classmethod
    def from_mapping(cls, table: dict, where: str = "training.toml [car]") -> CarSettings:
        simulator = table.get("simulator", DEFAULT_SIMULATOR)
        if simulator not in SIMULATORS:
            raise ConfigError(f"{where}: car.simulator {simulator!r} is not a simulator; use one of "
                              f"{', '.join(SIMULATORS)}")
        allowed = [k for k in CAR_KEYS if k not in ("simulator", "control")]
        overrides = []
        for key, value in table.items():
            if key == "simulator":
                continue
            if key not in allowed:
                raise ConfigError(f"{where}: unknown key car.{key}; allowed in [car]: simulator, "
                                  f"{', '.join(allowed)}")
            value = _coerce(where, f"car.{key}", getattr(CarParams(), key), value)
            why = implausible(key, value)
            if why:
                raise ConfigError(f"{where}: car.{key} = {why}, or remove the key to use the fitted one")
            try:
                CarParams(**{key: value})
            except ValueError as exc:
                raise ConfigError(f"{where}: car.{key} = {value!r}: {str(exc).removeprefix(f'CarParams.{key} ')}; "
                                  "fix the value or remove the key to use the fitted one") from None
            overrides.append((key, value))
        return cls(simulator, tuple(overrides))


@dataclass(frozen=True)
class TeacherSettings:
    """[teacher]: a camera (or other sensor) model learns a features teacher's actions first (`racerlab.train.distill`,
    docs/learner.md "A camera model from a features teacher")."""

    model: str = ""  # the teacher's model folder, relative to this one ("" = none: plain reinforcement learning)
    iterations: int = 30  # the model's own teacher trains this many iterations before the first round ...
    minutes: float = 2.0  # ... or for this long, whichever comes first (within --minutes)
    mix: float = 0.5  # share of steps the teacher drives in DAgger round k: mix ** k (round 0 is all teacher's)
    noise: float = 0.1  # Gaussian noise on the student's continuous actions while data is collected
    passes: float = 4.0  # gradient-step rows per new step collected (rows = passes x new steps)
    batch_size: int = 256
    lr: float = 0.0005
    max_steps: int = 60_000  # the aggregated data set's size (a camera frame is 19.2 kB)
    precision: str = "auto"  # auto (bfloat16 on CUDA and CPUs with bfloat16 units) | float32 | bfloat16


@dataclass(frozen=True)
class TrainingConfig:
    track: TrackSettings = field(default_factory=TrackSettings)
    run: RunSettings = field(default_factory=RunSettings)
    stop: StopSettings = field(default_factory=StopSettings)
    evaluation: EvaluationSettings = field(default_factory=EvaluationSettings)
    logs: LogSettings = field(default_factory=LogSettings)
    race: RaceConfig = field(default_factory=RaceConfig)  # [race]: DRfC's names (racerlab.spec.RaceConfig)
    randomise: RandomiseSettings = field(default_factory=RandomiseSettings)
    car: CarSettings = field(default_factory=CarSettings)  # [car]: the simulator's car (racerlab.spec.car_params)
    teacher: TeacherSettings = field(default_factory=TeacherSettings)  # [teacher]: learn a features model's actions
    source: str = "training.toml"
    # [[worker]] tables: what rollout worker k changes for itself ({section: {key: value}}), DRfC's multi-config
    workers: tuple[dict, ...] = ()

    def to_toml(self) -> str:
        out = []
        for f in fields(self):
            if f.name in ("source", "workers"):
                continue
            out.append(f"[{f.name}]")
            section = getattr(self, f.name)
            if isinstance(section, CarSettings):
                out.extend(f"{k} = {_toml_value(v)}" for k, v in section.table().items())
                out.append("")
                continue
            for sf in fields(section):
                if sf.name == "where":
                    continue
                out.append(f"{sf.name} = {_toml_value(getattr(section, sf.name))}")
            out.append("")
        for overlay in self.workers:
            out.append("[[worker]]")
            out.extend(f"{name}.{key} = {_toml_value(v)}" for name, keys in overlay.items() for key, v in keys.items())
            out.append("")
        return "\n".join(out)

    def for_worker(self, index: int) -> TrainingConfig:
        """The settings rollout worker `index` runs with: these, changed by its `[[worker]]` table if it has one."""
        if index >= len(self.workers):
            return replace(self, workers=())
        where = f"{self.source} [[worker]] {index + 1}"
        changed = {name: _parse_section(where, name, keys, getattr(self, name))
                   for name, keys in self.workers[index].items()}
        cfg = replace(self, **changed, workers=())
        _validate(replace(cfg, source=where))
        return cfg

    def worker_sets(self, index: int, section: str, key: str) -> bool:
        """Whether worker `index`'s `[[worker]]` table sets `section.key`."""
        return index < len(self.workers) and key in self.workers[index].get(section, {})


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, tuple | list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return repr(v)


SECTIONS = {"track": TrackSettings, "run": RunSettings, "stop": StopSettings, "evaluation": EvaluationSettings,
            "logs": LogSettings, "randomise": RandomiseSettings, "race": RaceConfig, "car": CarSettings,
            "teacher": TeacherSettings}


def _coerce(src: str, key: str, default, value):
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{src}: {key} must be true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{src}: {key} must be a whole number, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{src}: {key} must be a number, got {value!r}")
        return float(value)
    if isinstance(default, tuple):
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, list) or not value or not all(isinstance(x, str) for x in value):
            raise ConfigError(f"{src}: {key} must be a non-empty list of strings, got {value!r}")
        return tuple(value)
    if not isinstance(value, str):
        raise ConfigError(f"{src}: {key} must be a string, got {value!r}")
    return value


def parse_training_config(data: dict, source: str = "training.toml") -> TrainingConfig:
    sections = {}
    overlays = data.get("worker", [])
    if not isinstance(overlays, list) or not all(isinstance(o, dict) for o in overlays):
        raise ConfigError(f"{source}: worker must be an array of [[worker]] tables")
    for name, section in data.items():
        if name == "worker":
            continue
        if name not in SECTIONS:
            raise ConfigError(f"{source}: unknown section [{name}]; allowed: {', '.join(SECTIONS)}, [[worker]]")
        sections[name] = _parse_section(source, name, section, SECTIONS[name]())
    workers = []
    for k, overlay in enumerate(overlays):
        where = f"{source} [[worker]] {k + 1}"
        for name in overlay:
            if name not in SECTIONS:
                raise ConfigError(f"{where}: unknown section {name}; a worker may change "
                                  f"{', '.join(SECTIONS)} (for example track.names = [\"...\"])")
        workers.append({name: dict(section) for name, section in overlay.items()})
    cfg = TrainingConfig(**sections, source=source, workers=tuple(workers))
    _validate(cfg)
    for k in range(len(workers)):
        cfg.for_worker(k)  # each worker's settings are valid on their own
    return cfg


def _parse_section(source: str, name: str, section, base):
    """`base` (a settings dataclass, or the `RaceConfig`) with the keys of the TOML table `section` applied, each
    checked."""
    if not isinstance(section, dict):
        raise ConfigError(f"{source}: {name} must be a [section]")
    if isinstance(base, RaceConfig):  # DRfC's race keys: RaceConfig checks them itself
        return RaceConfig.from_mapping({**base.table(), **section}, where=f"{source} [race]")
    if isinstance(base, CarSettings):  # any CarParams constant: CarSettings checks them itself
        return CarSettings.from_mapping({**base.table(), **section}, where=source)
    cls = type(base)
    allowed = {f.name for f in fields(cls)}
    values = {}
    for key, value in section.items():
        if key not in allowed:
            raise ConfigError(f"{source}: unknown key {name}.{key}; allowed in [{name}]: "
                              f"{', '.join(sorted(allowed))}")
        values[key] = _coerce(source, f"{name}.{key}", getattr(cls(), key), value)
    return replace(base, **values)


def _check(ok: bool, source: str, message: str) -> None:
    if not ok:
        raise ConfigError(f"{source}: {message}")


def _validate(c: TrainingConfig) -> None:
    s = c.source
    _check(0 <= c.track.round_robin_advance < 1, s, "track.round_robin_advance must be in [0, 1)")
    _check(0 <= c.track.start_offset < 1, s, "track.start_offset must be in [0, 1)")
    _check(c.run.num_cars >= 1, s, "run.num_cars must be >= 1")
    _check(c.run.num_cars >= max(c.track.driven, c.track.generated), s,
           "run.num_cars must be at least the number of tracks driven at once (track.names, or track.at_once)")
    _validate_generated(c.track, s)
    _validate_randomise(c.randomise, s)
    _validate_teacher(c.teacher, s)
    _check(c.run.threads >= 0, s, "run.threads must be >= 0")
    base = split_observation_name(c.run.observation)[0]
    _check(base in ("", *OBSERVATION_NAMES), s,
           f"run.observation must be empty (follow model_metadata.json) or one of {', '.join(OBSERVATION_NAMES)}, "
           "optionally with options after a colon (camera:dr, lidar:walls)")
    _check(c.run.look in LOOKS, s, f"run.look is {c.run.look!r}; use one of {', '.join(LOOKS)} "
           "(aws: the AWS simulator's camera look, classic: racerlab's earlier one)")
    _check(c.run.reward_order in REWARD_ORDERS, s, f"run.reward_order must be one of {REWARD_ORDERS}")
    _check(c.run.max_steps_per_iteration >= 100, s, "run.max_steps_per_iteration must be >= 100")
    _check(c.run.max_episode_steps >= 10, s, "run.max_episode_steps must be >= 10")
    _check(c.run.reward_budget_s >= 0, s, "run.reward_budget_s must be >= 0 (0 = no limit)")
    for key in ("minutes", "episodes", "iterations"):
        value = getattr(c.stop, key)
        _check(value >= 0, s, f"stop.{key} must be >= 0 (0 = no limit), got {value:g}")
    _check(c.evaluation.episodes >= 0, s, "evaluation.episodes must be >= 0")
    _check(c.evaluation.best_model_metric in BEST_MODEL_METRICS, s,
           f"evaluation.best_model_metric must be one of {BEST_MODEL_METRICS}")
    _check(c.logs.simtrace_every >= 1, s, "logs.simtrace_every must be >= 1")
    _check(c.logs.plain_iterations >= 1, s, f"logs.plain_iterations must be >= 1, got {c.logs.plain_iterations}")
    _check(c.logs.max_mb >= 0, s, f"logs.max_mb must be >= 0 (0 = no budget), got {c.logs.max_mb:g}")
    _check(c.run.device == "auto" or c.run.device == "cpu" or c.run.device.startswith("cuda"), s,
           "run.device must be auto, cpu, cuda or cuda:N")


def _validate_generated(t: TrackSettings, s: str) -> None:
    _check(t.generated >= 0 and t.regenerate_every >= 0, s, "track.generated and track.regenerate_every must be >= 0")
    _check(t.at_once >= 0, s, "track.at_once must be >= 0 (0 = every named track at once)")
    _check(0 < t.generated_min_length <= t.generated_max_length <= 200, s,
           "track.generated_min_length <= generated_max_length must be in (0, 200] m")
    _check(0.3 <= t.generated_min_width <= t.generated_max_width <= 2.0, s,
           "track.generated_min_width <= generated_max_width must be in [0.3, 2] m")
    _check(t.generated_min_radius >= 0.3, s, "track.generated_min_radius must be >= 0.3 m (the car turns no tighter)")


def _validate_randomise(r: RandomiseSettings, s: str) -> None:
    for name in ("camera_noise", "blur", "pose_yaw_deg", "pose_pitch_deg", "pose_shift_m", "lidar_noise_m"):
        _check(getattr(r, name) >= 0, s, f"randomise.{name} must be >= 0")
    for name in ("exposure", "gamma", "steering_gain", "throttle_gain"):
        _check(0 <= getattr(r, name) < 1, s, f"randomise.{name} must be in [0, 1): a range around 1")
    _check(r.latency_steps in (0, 1, 2), s, "randomise.latency_steps must be 0, 1 or 2")
    _check(r.latency_steps > 0 or not r.latency_varies, s, "randomise.latency_varies draws each episode's latency "
           "from 0 to latency_steps: set latency_steps to 1 or 2, or remove latency_varies")
    _check(r.speed_scale > 0 and r.top_speed >= 0, s, "randomise.speed_scale must be > 0 and top_speed >= 0")


# [teacher]'s plausible values: (low, high, what the key means); absurd ones were an OverflowError (minutes = inf),
# a 17.5 TiB allocation (max_steps = 1e9: a camera frame is 19.2 kB) or a fit that never ends (passes = 1e9)
TEACHER_RANGES = {
    "iterations": (0, 10000, "iterations the model's own teacher trains"),
    "minutes": (0, 1440, "minutes the model's own teacher trains: a day at most"),
    "mix": (0, 1, "the teacher's share of round k is mix ** k"),
    "noise": (0, 2, "the spread of the student's exploring actions, which span [-1, 1]"),
    "passes": (0.001, 100, "fit rows per new step"),
    "batch_size": (1, 65536, "rows per fit step"),
    "lr": (1e-08, 1, "the fit's learning rate"),
    "max_steps": (1, 1000000, "steps in the data set; a million camera frames take 19 GB"),
}


def _validate_teacher(t: TeacherSettings, s: str) -> None:
    for key, (low, high, meaning) in TEACHER_RANGES.items():
        value = getattr(t, key)
        _check(math.isfinite(value) and low <= value <= high, s,
               f"teacher.{key} = {value!r} is outside its plausible range {low!r}..{high!r} ({meaning})")
    _check(t.max_steps >= t.batch_size, s, "teacher.batch_size must be >= 1 and teacher.max_steps at least "
           "teacher.batch_size")
    _check(t.precision in PRECISIONS, s, f"teacher.precision is {t.precision!r}; use one of {', '.join(PRECISIONS)}")


def load_training_config(path) -> TrainingConfig:
    p = Path(path)
    if not p.is_file():
        return TrainingConfig(source=str(p))
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8-sig"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: invalid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text (byte {exc.start}); save the file as UTF-8") from None
    except RecursionError:
        raise ConfigError(f"{p}: nested too deeply to be racerlab's training.toml; check its brackets") from None
    return parse_training_config(data, str(p))
