"""Observations to check an export with: what the car's sensors give, real where at hand, rendered otherwise.

`car_observations(shapes, n)` returns n observations for racerlab's inputs (`camera` (n, 120, 160, 1) uint8,
`stereo` (n, 120, 160, 2) uint8, `lidar` (n, 64) float32 m, `sector_lidar` (n, 8) bits):

- first the AWS simulator's own frames from `real_dir` (the `.npy` frames of `gazebo_frames`: greyscale
  120×160, stereo pairs 120×160×2; a single camera also takes each eye of the stereo pairs), each once;
- then racerlab's renders of cars at random poses on `track` (anywhere along the lap, up to 0.25 m either side
  of the centre line, heading within ±30° of the track's), with the lidar scanning the same poses (the track's
  borders seen as walls, so the ranges vary).

Real frames have no lidar scan of their own: a model with a lidar gets the scan of a rendered pose beside them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

SIDE_M, YAW_DEG = 0.25, 30.0


def real_frames(real_dir, channels: int) -> np.ndarray:
    """(k, 120, 160, channels) uint8 frames of the AWS simulator in `real_dir` (none if it is missing)."""
    out = []
    for f in sorted(Path(real_dir).glob("*.npy")) if real_dir and Path(real_dir).is_dir() else []:
        a = np.load(f, allow_pickle=False)
        if a.ndim == 2 and channels == 1:
            out.append(a[..., None])
        elif a.ndim == 3 and a.shape[-1] == 2:
            out.extend([a] if channels == 2 else [a[..., :1], a[..., 1:]])
    return np.stack(out).astype(np.uint8) if out else np.zeros((0, 120, 160, channels), np.uint8)


def random_poses(track, n: int, rng) -> np.ndarray:
    s = rng.uniform(0.0, track.length, n)
    side = rng.uniform(-SIDE_M, SIDE_M, n)
    heading = track.heading_at(s)
    xy = track.point_at(s) + side[:, None] * np.column_stack([-np.sin(heading), np.cos(heading)])
    return np.column_stack([xy, heading + np.radians(rng.uniform(-YAW_DEG, YAW_DEG, n))])


def rendered(shapes: dict, n: int, track="lab_technical", seed: int = 0) -> dict[str, np.ndarray]:
    """racerlab's observations of n cars at random poses (see the module docstring)."""
    from racerlab import track as tracks
    from racerlab.sim.poses import readings_at

    t = tracks.load(track)
    return readings_at(t, random_poses(t, n, np.random.default_rng(seed)), list(shapes), seed=seed)


def car_observations(shapes: dict, n: int, real_dir=None, track="lab_technical", seed: int = 0):
    """(observations, how many of them are the AWS simulator's own frames)."""
    images = [k for k in shapes if len(shapes[k]) == 3]
    real = real_frames(real_dir, shapes[images[0]][-1])[:n] if images else np.zeros((0,))
    obs = rendered(shapes, n, track, seed)
    if len(real):
        obs[images[0]][:len(real)] = real
    return obs, len(real)
