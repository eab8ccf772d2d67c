"""`training.toml`: racerlab's run settings for a model folder (what DRfC keeps in run.env).

Sections and defaults live in `DEFAULTS`; unknown sections or keys and wrong types are a
`ConfigError` naming the file and the key. Command-line flags override the file.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path

from racerlab.errors import ConfigError
from racerlab.logs.metrics import BEST_MODEL_METRICS
from racerlab.model.metadata import OBSERVATION_NAMES, split_observation_name
from racerlab.spec import RaceConfig

REWARD_ORDERS = ("aws", "after_action")


@dataclass(frozen=True)
class TrackSettings:
    names: tuple[str, ...] = ("lab_technical",)  # several tracks: the cars are spread over them
    reverse: bool = False  # REVERSE_DIR
    alternate_direction: bool = False  # ALTERNATE_DRIVING_DIRECTION
    change_start: bool = True  # CHANGE_START_POSITION
    round_robin_advance: float = 0.05  # ROUND_ROBIN_ADVANCE_DIST
    start_offset: float = 0.0  # START_POSITION_OFFSET


@dataclass(frozen=True)
class RunSettings:
    num_cars: int = 32  # cars simulated in parallel (DRfC: workers)
    seed: int = 0
    device: str = "auto"  # auto | cpu | cuda | cuda:N
    threads: int = 0  # torch CPU threads; 0 = all cores
    observation: str = ""  # "" follows model_metadata.json's sensor list
    reward_order: str = "aws"  # aws | after_action (see racerlab.sim)
    max_steps_per_iteration: int = 10_000  # AWS MAX_MEMORY_STEPS: whole episodes beyond it are dropped
    max_episode_steps: int = 10_000


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
    compress: bool = False  # gzip the simtrace CSVs (smaller; some older tools read only plain CSV)


@dataclass(frozen=True)
class TrainingConfig:
    track: TrackSettings = field(default_factory=TrackSettings)
    run: RunSettings = field(default_factory=RunSettings)
    stop: StopSettings = field(default_factory=StopSettings)
    evaluation: EvaluationSettings = field(default_factory=EvaluationSettings)
    logs: LogSettings = field(default_factory=LogSettings)
    race: RaceConfig = field(default_factory=RaceConfig)  # [race]: DRfC's names (racerlab.spec.RaceConfig)
    source: str = "training.toml"

    def to_toml(self) -> str:
        out = []
        for f in fields(self):
            if f.name == "source":
                continue
            out.append(f"[{f.name}]")
            section = getattr(self, f.name)
            for sf in fields(section):
                if sf.name == "where":
                    continue
                out.append(f"{sf.name} = {_toml_value(getattr(section, sf.name))}")
            out.append("")
        return "\n".join(out)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, tuple | list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return repr(v)


SECTIONS = {"track": TrackSettings, "run": RunSettings, "stop": StopSettings, "evaluation": EvaluationSettings,
            "logs": LogSettings}


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
    for name, section in data.items():
        if name not in SECTIONS and name != "race":
            raise ConfigError(f"{source}: unknown section [{name}]; allowed: {', '.join(SECTIONS)}, race")
        if not isinstance(section, dict):
            raise ConfigError(f"{source}: {name} must be a [section]")
        if name == "race":
            sections[name] = RaceConfig.from_mapping(section, where=f"{source} [race]")
            continue
        cls = SECTIONS[name]
        defaults = cls()
        allowed = {f.name for f in fields(cls)}
        values = {}
        for key, value in section.items():
            if key not in allowed:
                raise ConfigError(f"{source}: unknown key {name}.{key}; allowed in [{name}]: "
                                  f"{', '.join(sorted(allowed))}")
            values[key] = _coerce(source, f"{name}.{key}", getattr(defaults, key), value)
        sections[name] = cls(**values)
    cfg = TrainingConfig(**sections, source=source)
    _validate(cfg)
    return cfg


def _check(ok: bool, source: str, message: str) -> None:
    if not ok:
        raise ConfigError(f"{source}: {message}")


def _validate(c: TrainingConfig) -> None:
    s = c.source
    _check(0 <= c.track.round_robin_advance < 1, s, "track.round_robin_advance must be in [0, 1)")
    _check(0 <= c.track.start_offset < 1, s, "track.start_offset must be in [0, 1)")
    _check(c.run.num_cars >= 1, s, "run.num_cars must be >= 1")
    _check(c.run.num_cars >= len(c.track.names), s, "run.num_cars must be at least the number of tracks")
    _check(c.run.threads >= 0, s, "run.threads must be >= 0")
    base = split_observation_name(c.run.observation)[0]
    _check(base in ("", *OBSERVATION_NAMES), s,
           f"run.observation must be empty (follow model_metadata.json) or one of {', '.join(OBSERVATION_NAMES)}, "
           "optionally with options after a colon (camera:dr, lidar:walls)")
    _check(c.run.reward_order in REWARD_ORDERS, s, f"run.reward_order must be one of {REWARD_ORDERS}")
    _check(c.run.max_steps_per_iteration >= 100, s, "run.max_steps_per_iteration must be >= 100")
    _check(c.run.max_episode_steps >= 10, s, "run.max_episode_steps must be >= 10")
    _check(c.stop.minutes >= 0 and c.stop.episodes >= 0 and c.stop.iterations >= 0, s,
           "stop values must be >= 0")
    _check(c.evaluation.episodes >= 0, s, "evaluation.episodes must be >= 0")
    _check(c.evaluation.best_model_metric in BEST_MODEL_METRICS, s,
           f"evaluation.best_model_metric must be one of {BEST_MODEL_METRICS}")
    _check(c.logs.simtrace_every >= 1, s, "logs.simtrace_every must be >= 1")
    _check(c.run.device == "auto" or c.run.device == "cpu" or c.run.device.startswith("cuda"), s,
           "run.device must be auto, cpu, cuda or cuda:N")


def load_training_config(path) -> TrainingConfig:
    p = Path(path)
    if not p.is_file():
        return TrainingConfig(source=str(p))
    try:
        data = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: invalid TOML: {exc}") from None
    return parse_training_config(data, str(p))
