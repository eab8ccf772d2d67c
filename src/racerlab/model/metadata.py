"""`model_metadata.json`: the AWS action space, sensors, network and algorithm of a model.

Parsed as the AWS simulator parses it (facts §5), into frozen dataclasses; every unknown key or
wrong value is a `ConfigError` that names the file, the key and what is allowed.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from racerlab.errors import ConfigError
from racerlab.spec import MAX_STEERING_DEG

CAMERAS = ("FRONT_FACING_CAMERA", "LEFT_CAMERA", "STEREO_CAMERAS", "observation")
LIDARS = ("LIDAR", "SECTOR_LIDAR", "DISCRETIZED_SECTOR_LIDAR")
NETWORKS = ("DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "DEEP_CONVOLUTIONAL_NETWORK", "DEEP_CONVOLUTIONAL_NETWORK_DEEP",
            "MLP")  # MLP: racerlab's network for the `features` observation
ALGORITHMS = ("clipped_ppo", "sac")
KNOWN_KEYS = {"action_space", "action_space_type", "sensor", "neural_network", "training_algorithm", "version",
              "lidar_config", "preprocess_type", "racerlab"}

# What a model may observe (training.toml's run.observation): racerlab's `features` vector and the sensor
# combinations. `racerlab.sim.observations` builds each; an observation registered there is added with
# `accept_observation_name`.
OBSERVATION_NAMES = ["features", "camera", "stereo", "lidar", "sector_lidar", "discretized_sector_lidar",
                     "camera+lidar", "camera+sector_lidar", "camera+discretized_sector_lidar", "stereo+lidar",
                     "stereo+sector_lidar", "stereo+discretized_sector_lidar"]


def accept_observation_name(name: str) -> None:
    """Let training.toml's run.observation name a newly registered observation."""
    if name not in OBSERVATION_NAMES:
        OBSERVATION_NAMES.append(name)


def split_observation_name(name: str) -> tuple[str, tuple[str, ...]]:
    """"stereo+lidar:dr,walls" -> ("stereo+lidar", ("dr", "walls"))."""
    base, _, opts = name.partition(":")
    return base.strip(), tuple(o.strip() for o in opts.split(",") if o.strip())


@dataclass(frozen=True)
class DiscreteActions:
    """A list of (steering °, speed m/s) pairs; index i is action i."""

    steering_deg: tuple[float, ...]
    speed: tuple[float, ...]

    @property
    def n(self) -> int:
        return len(self.speed)

    @property
    def top_speed(self) -> float:
        """The fastest action's speed, m/s (what the physical car's full throttle stands for)."""
        return float(max(self.speed))

    def lookup(self, index) -> tuple[np.ndarray, np.ndarray]:
        """Commanded (steering °, speed) for integer action indices (any shape)."""
        idx = np.asarray(index, dtype=np.int64)
        return np.asarray(self.steering_deg)[idx], np.asarray(self.speed)[idx]

    def to_json(self) -> list[dict]:
        return [{"steering_angle": s, "speed": v, "index": i}
                for i, (s, v) in enumerate(zip(self.steering_deg, self.speed, strict=True))]


@dataclass(frozen=True)
class ContinuousActions:
    """Ranges for continuous actions; the agent acts in [-1, 1]² as [steer, speed]."""

    steering_low: float
    steering_high: float
    speed_low: float
    speed_high: float

    @property
    def top_speed(self) -> float:
        """The range's top speed, m/s (what the physical car's full throttle stands for)."""
        return float(self.speed_high)

    def rescale(self, action) -> tuple[np.ndarray, np.ndarray]:
        """Clip to [-1, 1] and rescale linearly to the ranges, as AWS's ScalableBoxActionSpace does."""
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        steer = self.steering_low + (a[..., 0] + 1.0) * 0.5 * (self.steering_high - self.steering_low)
        speed = self.speed_low + (a[..., 1] + 1.0) * 0.5 * (self.speed_high - self.speed_low)
        return steer, speed

    def to_json(self) -> dict:
        return {"steering_angle": {"low": self.steering_low, "high": self.steering_high},
                "speed": {"low": self.speed_low, "high": self.speed_high}}


@dataclass(frozen=True)
class ModelMetadata:
    actions: DiscreteActions | ContinuousActions
    sensor: tuple[str, ...] = ("FRONT_FACING_CAMERA",)
    neural_network: str = "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
    training_algorithm: str = "clipped_ppo"
    version: float = 5.0
    lidar_config: dict = field(default_factory=dict)
    source: str = "model_metadata.json"

    @property
    def action_space_type(self) -> str:
        return "discrete" if isinstance(self.actions, DiscreteActions) else "continuous"

    @property
    def camera(self) -> str | None:
        return next((s for s in self.sensor if s in CAMERAS), None)

    @property
    def lidar(self) -> str | None:
        return next((s for s in self.sensor if s in LIDARS), None)

    def differences(self, other: ModelMetadata) -> list[str]:
        """What weights trained with this metadata cannot carry over to `other` (facts §9): the action space type,
        the number of discrete actions, the sensors, the network and the algorithm, each as "what: mine → other's".
        Action values (the speeds and angles), the reward, hyperparameters and track may change."""
        out = []
        if self.action_space_type != other.action_space_type:
            out.append(f"action space type {self.action_space_type} → {other.action_space_type}")
        elif self.action_space_type == "discrete" and self.actions.n != other.actions.n:
            out.append(f"number of actions {self.actions.n} → {other.actions.n}")
        if tuple(self.sensor) != tuple(other.sensor):
            out.append(f"sensors {list(self.sensor)} → {list(other.sensor)}")
        for name in ("neural_network", "training_algorithm"):
            if getattr(self, name) != getattr(other, name):
                out.append(f"{name} {getattr(self, name)} → {getattr(other, name)}")
        return out

    def to_json(self) -> dict:
        out = {"action_space": self.actions.to_json(), "action_space_type": self.action_space_type,
               "sensor": list(self.sensor), "neural_network": self.neural_network,
               "training_algorithm": self.training_algorithm, "version": _fmt_version(self.version)}
        if self.lidar_config:
            out["lidar_config"] = dict(self.lidar_config)
        return out


def _fmt_version(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else str(v)


def default_discrete_actions(max_steer: float = MAX_STEERING_DEG, steer_levels: int = 5, max_speed: float = 1.0,
                             speed_levels: int = 2) -> DiscreteActions:
    """The console default: steering evenly over [-max, max] (outer loop) × speeds max·i/n (DRoA, facts §5)."""
    steers = np.linspace(-max_steer, max_steer, steer_levels)
    speeds = [max_speed * (i + 1) / speed_levels for i in range(speed_levels)]
    pairs = [(float(s), float(v)) for s in steers for v in speeds]
    return DiscreteActions(tuple(p[0] for p in pairs), tuple(p[1] for p in pairs))


DEFAULT_CONTINUOUS = ContinuousActions(-MAX_STEERING_DEG, MAX_STEERING_DEG, 1.0, 2.0)


def parse_number(src: str, key: str, value) -> float:
    """A finite number (numbers written as strings accepted, as AWS files have them) or a ConfigError."""
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise ConfigError(f"{src}: {key} must be a number, got {value!r}")
    try:
        x = float(value)
    except ValueError:
        raise ConfigError(f"{src}: {key} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ConfigError(f"{src}: {key} must be finite, got {value!r}")
    return x


def _steering(src: str, key: str, value) -> float:
    """A steering angle in degrees; AWS refuses more than ±30° (the car's steering limit)."""
    v = parse_number(src, key, value)
    if abs(v) > MAX_STEERING_DEG:
        raise ConfigError(f"{src}: {key} is {v:g}°; the car steers at most ±{MAX_STEERING_DEG:g}° (AWS refuses "
                          f"more): use a value between -{MAX_STEERING_DEG:g} and {MAX_STEERING_DEG:g}")
    return v


def _parse_discrete(src: str, space) -> DiscreteActions:
    if not isinstance(space, list) or not space:
        raise ConfigError(f"{src}: action_space must be a non-empty list of "
                          '{"steering_angle": degrees, "speed": m/s} for action_space_type "discrete"')
    steers, speeds = [], []
    for i, a in enumerate(space):
        if not isinstance(a, dict) or "steering_angle" not in a or "speed" not in a:
            raise ConfigError(f"{src}: action_space[{i}] must have steering_angle and speed, got {a!r}")
        extra = set(a) - {"steering_angle", "speed", "index"}
        if extra:
            raise ConfigError(f"{src}: action_space[{i}] has unknown keys {sorted(extra)}; "
                              "allowed: steering_angle, speed, index")
        steers.append(_steering(src, f"action_space[{i}].steering_angle", a["steering_angle"]))
        v = parse_number(src, f"action_space[{i}].speed", a["speed"])
        if v <= 0:
            raise ConfigError(f"{src}: action_space[{i}].speed must be > 0 m/s, got {v}")
        speeds.append(v)
    return DiscreteActions(tuple(steers), tuple(speeds))


def _parse_continuous(src: str, space) -> ContinuousActions:
    if not isinstance(space, dict) or set(space) != {"steering_angle", "speed"}:
        raise ConfigError(f"{src}: continuous action_space must be "
                          '{"steering_angle": {"low": .., "high": ..}, "speed": {"low": .., "high": ..}}')
    vals = {}
    for dim in ("steering_angle", "speed"):
        rng = space[dim]
        if not isinstance(rng, dict) or set(rng) != {"low", "high"}:
            raise ConfigError(f"{src}: action_space.{dim} must be {{\"low\": .., \"high\": ..}}, got {rng!r}")
        number = _steering if dim == "steering_angle" else parse_number
        lo = number(src, f"action_space.{dim}.low", rng["low"])
        hi = number(src, f"action_space.{dim}.high", rng["high"])
        if not lo < hi:
            raise ConfigError(f"{src}: action_space.{dim}: low ({lo}) must be smaller than high ({hi})")
        vals[dim] = (lo, hi)
    if vals["speed"][0] <= 0:
        raise ConfigError(f"{src}: action_space.speed.low must be > 0 m/s")
    return ContinuousActions(*vals["steering_angle"], *vals["speed"])


def _parse_sensor(src: str, sensor) -> tuple[str, ...]:
    if isinstance(sensor, str):
        sensor = [sensor]
    if not isinstance(sensor, list) or not all(isinstance(s, str) for s in sensor):
        raise ConfigError(f"{src}: sensor must be a list of names, got {sensor!r}")
    unknown = [s for s in sensor if s not in CAMERAS + LIDARS + ("FEATURES",)]
    if unknown:
        raise ConfigError(f"{src}: unknown sensor {unknown[0]!r}; allowed: {', '.join(CAMERAS + LIDARS)} "
                          "(or racerlab's FEATURES)")
    if sum(s in CAMERAS for s in sensor) > 1 or sum(s in LIDARS for s in sensor) > 1:
        raise ConfigError(f"{src}: sensor may hold one camera and at most one lidar, got {sensor}")
    return tuple(sensor)


def parse_model_metadata(data: dict, source: str = "model_metadata.json") -> ModelMetadata:
    """Validate a model_metadata dict the way the AWS simulator reads it."""
    src = source
    if not isinstance(data, dict):
        raise ConfigError(f"{src}: expected a JSON object, got {type(data).__name__}")
    unknown = set(data) - KNOWN_KEYS
    if unknown:
        raise ConfigError(f"{src}: unknown key {sorted(unknown)[0]!r}; allowed: {', '.join(sorted(KNOWN_KEYS))}")
    kind = data.get("action_space_type", "discrete")
    if kind not in ("discrete", "continuous"):
        raise ConfigError(f"{src}: action_space_type must be \"discrete\" or \"continuous\", got {kind!r}")
    if "action_space" not in data:
        raise ConfigError(f"{src}: missing key 'action_space'")
    actions = (_parse_discrete if kind == "discrete" else _parse_continuous)(src, data["action_space"])
    algo = data.get("training_algorithm", "clipped_ppo")
    if algo not in ALGORITHMS:
        raise ConfigError(f"{src}: training_algorithm must be one of {ALGORITHMS}, got {algo!r}")
    if algo == "sac" and kind != "continuous":
        raise ConfigError(f"{src}: training_algorithm \"sac\" needs action_space_type \"continuous\"")
    net = data.get("neural_network", NETWORKS[0])
    if net not in NETWORKS:
        raise ConfigError(f"{src}: neural_network must be one of {NETWORKS}, got {net!r}")
    sensor = _parse_sensor(src, data["sensor"]) if "sensor" in data else ("observation",)
    default_version = 2.0 if "sensor" in data else 1.0
    version = parse_number(src, "version", data.get("version", default_version))
    lidar_config = data.get("lidar_config", {})
    if not isinstance(lidar_config, dict):
        raise ConfigError(f"{src}: lidar_config must be an object")
    return ModelMetadata(actions, sensor, net, algo, version, dict(lidar_config), src)


def read_json_file(path):
    """A JSON config file's content; a missing file or bad JSON is a one-line ConfigError."""
    p = Path(path)
    try:
        return json.loads(p.read_bytes())  # bytes: UTF-8 (with or without a BOM), UTF-16 and UTF-32 are all read
    except FileNotFoundError:
        raise ConfigError(f"{p}: file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{p}: a folder, not a JSON file") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{p}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text (byte {exc.start}: {exc.object[exc.start:exc.start + 1]!r}); "
                          "save the file as UTF-8") from None
    except RecursionError:
        raise ConfigError(f"{p}: nested too deeply to be a DeepRacer file; check its brackets") from None


def load_model_metadata(path) -> ModelMetadata:
    return parse_model_metadata(read_json_file(path), str(path))


def as_model_metadata(value) -> ModelMetadata:
    """Accept a `ModelMetadata`, a dict, a path, or None (the console's default discrete space)."""
    if value is None:
        return ModelMetadata(default_discrete_actions(), ("FRONT_FACING_CAMERA",))
    if isinstance(value, ModelMetadata):
        return value
    if isinstance(value, dict):
        return parse_model_metadata(value, "model_metadata (dict)")
    return load_model_metadata(value)
