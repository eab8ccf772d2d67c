"""Synthetic simtrace data with realistic shapes and units, for tests and benchmarks (not for analysis).

A car drives around a circle of radius 2.5 m: positions in metres, yaw and steer in degrees, 15 steps
per simulated second, the first row of each episode a `prepare` step, the last one `off_track` or
`lap_complete`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from racerlab.logs.layout import training_simtrace_path
from racerlab.logs.simtrace import SimtraceWriter
from racerlab.spec import STEPS_PER_SECOND

TRACK_LEN = 2 * np.pi * 2.5


def episode_columns(episodes: np.ndarray, steps: np.ndarray, rng: np.random.Generator,
                    continuous: bool = False, wall_start: float = 1.7e9) -> dict[str, np.ndarray]:
    """The 19 simtrace columns for the given episode numbers, `steps[i]` rows for episode i."""
    n = int(steps.sum())
    ep = np.repeat(episodes, steps)
    first = np.concatenate([[0], np.cumsum(steps)[:-1]])
    step = np.arange(n) - np.repeat(first, steps) + 1
    start = np.repeat(rng.uniform(0, 100, len(episodes)), steps)
    progress = np.minimum(100.0, (step - 1) * 0.8 + rng.uniform(0, 0.1, n))
    angle = 2 * np.pi * (start + progress) / 100
    last = np.repeat(first + steps - 1, steps) == np.arange(n)
    lap = last & (progress >= 100)
    status = np.where(step == 1, "prepare", np.where(last, np.where(lap, "lap_complete", "off_track"), "in_progress"))
    steer = rng.choice([-30.0, -15.0, 0.0, 15.0, 30.0], n)
    speed = rng.choice([1.0, 2.0, 3.0], n)
    action = np.stack([steer, speed], 1) if continuous else ((steer + 30) // 15 * 3 + speed - 1).astype(np.int64)
    tstamp = np.round(np.repeat(rng.uniform(0, 5000, len(episodes)), steps) + step / STEPS_PER_SECOND, 3)
    return {
        "episode": ep, "steps": step, "X": 2.5 * np.cos(angle), "Y": 2.5 * np.sin(angle),
        "yaw": np.degrees(np.arctan2(np.cos(angle), -np.sin(angle))), "steer": steer, "throttle": speed,
        "action": action, "reward": np.where(step == 1, 0.0, rng.uniform(0, 2, n)), "done": last,
        "all_wheels_on_track": ~(last & ~lap), "progress": progress,
        "closest_waypoint": (angle / (2 * np.pi) * 120).astype(np.int64) % 120, "track_len": np.full(n, TRACK_LEN),
        "tstamp": tstamp, "episode_status": status, "pause_duration": np.zeros(n),
        "obstacle_crash_counter": np.zeros(n, np.int64), "wall_clock": wall_start + tstamp,
    }


def write_training_folder(folder: str | os.PathLike, iterations: int, episodes_per_worker: int, workers: int = 1,
                          mean_steps: int = 120, seed: int = 0, compress: bool = False,
                          continuous: bool = False) -> int:
    """A DRfC-layout training folder (`<folder>/training-simtrace` for one worker, `<folder>/<k>/...` for
    several); each worker counts its episodes from 0 as the simulator does. Returns the rows written."""
    rng = np.random.default_rng(seed)
    rows = 0
    for w in range(workers):
        base = Path(folder) / str(w) if workers > 1 else Path(folder)
        for it in range(iterations):
            episodes = np.arange(it * episodes_per_worker, (it + 1) * episodes_per_worker)
            steps = rng.integers(max(2, mean_steps // 4), mean_steps * 7 // 4, len(episodes))
            cols = episode_columns(episodes, steps, rng, continuous=continuous)
            with SimtraceWriter(training_simtrace_path(base, it), compress=compress) as writer:
                rows += writer.write(cols)
    return rows
