"""Observations by name: each builds a batched observation of the simulator's current poses.

`features` is racerlab's compact vector for fast training (see `_kernels.features`); the
sensors (camera, stereo, lidar, sector lidar and a camera with a lidar, `racerlab.sim.sensors`)
register here under their own names. When the environment is given no `observation`, it
follows the model's `sensor` list as AWS does.

A name may carry options after a colon, comma-separated, which go to the factory as
`options`: ``"camera:dr"`` (domain randomization of the camera), ``"stereo+lidar:dr,walls"``
(and the lidar sees the track borders as walls). See `racerlab.sim.sensors`.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

import gymnasium as gym
import numpy as np

from racerlab.errors import ConfigError
from racerlab.model.metadata import (
    OBSERVATION_NAMES,
    ModelMetadata,
    accept_observation_name,
    split_observation_name,
)

FEATURE_LIMIT = 10.0


class FeaturesObservation:
    """The `features` vector: speed, steering, offset, heading error, width and centre points ahead."""

    name = "features"
    partial_update = True

    def __init__(self, sim, metadata: ModelMetadata | None = None):
        self.sim = sim
        self._buf = np.empty((sim.num_cars, sim.feature_size))

    @property
    def space(self) -> gym.Space:
        return gym.spaces.Box(-FEATURE_LIMIT, FEATURE_LIMIT, shape=(self.sim.feature_size,), dtype=np.float32)

    def __call__(self, rows=None) -> np.ndarray:
        # a car far off the track has a large offset; clipping keeps the vector inside its space
        self.sim.features(self._buf, rows)
        return np.clip(self._buf, -FEATURE_LIMIT, FEATURE_LIMIT).astype(np.float32)


# name -> factory(sim, metadata) returning an object with `.space` (one car) and `__call__(rows=None)`
# giving the batch; with `partial_update = True` it also accepts `rows` (indices of the only cars that
# changed since the last call, after a partial reset). A factory that takes options is called with
# `options=` (a tuple of names) when the observation name has any.
OBSERVATIONS: dict[str, Callable] = {"features": FeaturesObservation}


def register_observation(name: str, factory: Callable) -> None:
    """Add an observation `name` (one training.toml's run.observation then accepts) built by `factory`."""
    OBSERVATIONS[name] = factory
    accept_observation_name(name)


def _sensor_factory(name: str) -> Callable:
    def factory(sim, metadata=None, options=()):
        from racerlab.sim.sensors import build_observation  # compiled kernels load only when a sensor is used

        return build_observation(name, sim, metadata, options)

    factory.__name__ = f"{name.replace('+', '_')}_observation"
    return factory


SENSOR_NAMES = tuple(name for name in OBSERVATION_NAMES if name != "features")
OBSERVATIONS.update({name: _sensor_factory(name) for name in SENSOR_NAMES})  # names model already accepts


def observation_name_for(metadata: ModelMetadata) -> str:
    """The observation AWS would build from the model's sensor list (facts §4)."""
    sensors = set(metadata.sensor)
    if "FEATURES" in sensors:
        return "features"
    cam = metadata.camera
    lidar = metadata.lidar
    if cam == "STEREO_CAMERAS":
        name = "stereo"
    elif cam is not None:
        name = "camera"
    else:
        name = None
    if lidar is not None:
        lid = lidar.lower()  # lidar, sector_lidar, discretized_sector_lidar
        name = f"{name}+{lid}" if name else lid
    return name or "features"


def make_observation(name: str | None, sim, metadata: ModelMetadata):
    name = name or observation_name_for(metadata)
    base, options = split_observation_name(name)
    if base not in OBSERVATIONS:
        raise ConfigError(f"observation {base!r} is not available; choose one of {', '.join(sorted(OBSERVATIONS))}")
    factory = OBSERVATIONS[base]
    if not options:
        return factory(sim, metadata)
    if "options" not in inspect.signature(factory).parameters:
        raise ConfigError(f"observation {base!r} takes no options, got {name!r}")
    return factory(sim, metadata, options=options)
