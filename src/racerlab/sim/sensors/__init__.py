"""Sensors: the front camera, the stereo camera, the lidar and the sector lidar (facts §4).

Each is an observation (registered by name in `racerlab.sim.observations`) that reads the poses of
every car of a `Simulator` and returns the batch: `camera` (B, 120, 160, 1) uint8, `stereo`
(B, 120, 160, 2) uint8, `lidar` (B, 64) float32, `sector_lidar` (B, 8) float32,
`discretized_sector_lidar` (B, sectors × values) float32 (set by the model's `lidar_config`). A
camera with a lidar, as AWS combines them, is a dict of the two keyed by those names
("camera+lidar", "stereo+lidar", "camera+sector_lidar", ...).

Options follow the name after a colon, comma-separated:
- `dr`: domain randomization of the camera's look per episode (`look.DomainRandomization`);
- `walls`: the lidar sees the track borders as walls (AWS's tracks have none; off by default);
- a look's name (`look.LOOKS`: `aws`, the default, or `classic`): how the world looks to the camera
  (training.toml's `run.look` adds it through the `World`).
e.g. ``observation="camera:dr"``, ``observation="stereo+lidar:dr,walls"`` or ``observation="camera:classic"``.

    >>> from racerlab.sim import Simulator
    >>> from racerlab.sim.sensors import build_observation
    >>> sim = Simulator(track, num_cars=64, seed=1)
    >>> cam = build_observation("camera", sim, options=("dr",))
    >>> cam().shape
    (64, 120, 160, 1)
"""

from __future__ import annotations

import gymnasium as gym

from racerlab.errors import ConfigError
from racerlab.sim.sensors.camera import Camera, CameraObservation
from racerlab.sim.sensors.lidar import Lidar, LidarObservation
from racerlab.sim.sensors.look import LOOKS, DomainRandomization, TrackLook

CAMERAS = ("camera", "stereo")
LIDARS = ("lidar", "sector_lidar", "discretized_sector_lidar")
SENSOR_OBSERVATIONS = CAMERAS + LIDARS + tuple(f"{c}+{li}" for c in CAMERAS for li in LIDARS)
OPTIONS = {"dr": "domain randomization of the camera", "walls": "the lidar sees the track borders as walls",
           "aws": "the AWS simulator's camera look (the default)", "classic": "racerlab's earlier camera look"}

__all__ = ["CAMERAS", "LIDARS", "LOOKS", "OPTIONS", "SENSOR_OBSERVATIONS", "Camera", "CameraObservation",
           "CombinedObservation", "DomainRandomization", "Lidar", "LidarObservation", "TrackLook",
           "build_observation"]


class CombinedObservation:
    """A camera and a lidar together: a dict of their batches, keyed by their names."""

    partial_update = True

    def __init__(self, parts):
        self.parts = {p.name: p for p in parts}
        self.name = "+".join(self.parts)

    @property
    def space(self) -> gym.Space:
        return gym.spaces.Dict({k: p.space for k, p in self.parts.items()})

    def __call__(self, rows=None) -> dict:
        return {k: p(rows) for k, p in self.parts.items()}


def build_observation(name: str, sim, metadata=None, options=()):
    """The sensor observation `name` (one of SENSOR_OBSERVATIONS) for `sim`, with `options` (OPTIONS keys)."""
    opts = set(options)
    unknown = sorted(opts - set(OPTIONS))
    if unknown:
        raise ConfigError(f"observation {name!r}: unknown option {unknown[0]!r}; options are "
                          + ", ".join(f"{k} ({v})" for k, v in OPTIONS.items()))
    parts = name.split("+")
    if name not in SENSOR_OBSERVATIONS:
        raise ConfigError(f"observation {name!r} is not a sensor; choose one of {', '.join(SENSOR_OBSERVATIONS)}")
    if "dr" in opts and parts[0] not in CAMERAS:
        raise ConfigError(f"observation {name!r}: option 'dr' randomizes a camera, and {name!r} has none")
    if "walls" in opts and parts[-1] not in LIDARS:
        raise ConfigError(f"observation {name!r}: option 'walls' is for a lidar, and {name!r} has none")
    looks = sorted(opts & set(LOOKS))
    if len(looks) > 1 or (looks and parts[0] not in CAMERAS):
        raise ConfigError(f"observation {name!r}: options {', '.join(looks)} pick a camera's look; give at most "
                          f"one, to an observation with a camera")
    look = LOOKS[looks[0] if looks else "aws"]
    built = []
    for p in parts:
        if p in CAMERAS:
            built.append(CameraObservation(sim, stereo=p == "stereo", look=look,
                                           randomization=DomainRandomization() if "dr" in opts else None))
        else:
            built.append(LidarObservation(sim, walls="walls" in opts, kind=p,
                                          lidar_config=getattr(metadata, "lidar_config", None),
                                          source=getattr(metadata, "source", "model_metadata.json")))
    return built[0] if len(built) == 1 else CombinedObservation(built)
