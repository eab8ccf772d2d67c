"""Observations by name: each builds a batched observation of the simulator's current poses.

`features` is racerlab's compact vector for fast training (see `_kernels.features`); the
sensors (camera, stereo, lidar, sector lidar) register here under their own names. When the
environment is given no `observation`, it follows the model's `sensor` list as AWS does.
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

from racerlab.errors import ConfigError
from racerlab.metadata import ModelMetadata

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
# changed since the last call, after a partial reset)
OBSERVATIONS: dict[str, Callable] = {"features": FeaturesObservation}


def register_observation(name: str, factory: Callable) -> None:
    OBSERVATIONS[name] = factory


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
        lid = "lidar" if lidar == "LIDAR" else "sector_lidar"
        name = f"{name}+{lid}" if name else lid
    return name or "features"


def make_observation(name: str | None, sim, metadata: ModelMetadata):
    name = name or observation_name_for(metadata)
    if name not in OBSERVATIONS:
        raise ConfigError(f"observation {name!r} is not available; choose one of {', '.join(sorted(OBSERVATIONS))}")
    return OBSERVATIONS[name](sim, metadata)
