"""Sensor readings of cars placed at given poses, without driving them: what a check of an exported model feeds
the model beside racerlab's own policy (`racerlab.exchange.frames`)."""

from __future__ import annotations

import numpy as np

from racerlab.sim.core import Simulator


def readings_at(track, poses, keys, seed: int = 0) -> dict[str, np.ndarray]:
    """{key: the readings of cars at `poses` ((n, 3): x, y, yaw)} for each of `keys`: `camera` and `stereo`
    (uint8 frames), `lidar` (ranges, m, the track's borders seen as walls so that they vary) and `sector_lidar` (its
    eight sector bits as float32)."""
    from racerlab.sim.sensors import Camera
    from racerlab.sim.sensors.lidar import Lidar, sectors

    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    sim = Simulator(track, len(poses), seed=seed)
    for i, (x, y, yaw) in enumerate(poses):
        sim.set_pose(i, x, y, yaw, start_ndist=0.0)
    out = {}
    for key in keys:
        if key in ("camera", "stereo"):
            out[key] = Camera(sim, stereo=key == "stereo").render().copy()
        elif key in ("lidar", "sector_lidar"):
            ranges = Lidar(sim, walls=True).scan().copy()
            out[key] = ranges if key == "lidar" else sectors(ranges).astype(np.float32)
        else:
            raise ValueError(f"no rendered observation for input {key!r}")
    return out
