"""Object avoidance that learns: time from a fresh `racerlab init --race object_avoidance` model to its first
greedy evaluation lap with no crash.

The model folder is exactly what `racerlab init --race object_avoidance` writes (three fixed boxes on the
default track, `[[0.25, 1], [0.5, -1], [0.75, 1]]`, and the example reward that reads `objects_*`), with the
chosen sensor and top speed (1 m/s by default, as `racerlab init` writes it). Training ends the episode at a
crash, so an evaluation lap that completes is a lap with no crash. Prints one JSON line; the target is <= 600 s
on the project's 2-core machine. `--threads` sets `[run] threads` (torch CPU threads; 0 = all cores, as
`racerlab train` runs by default; 1 avoids oversubscribing a machine that other jobs load).

Usage: python benchmarks/object_avoidance.py [--sensor features|lidar] [--max-speed 1.0] [--minutes 15] [--threads 0]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from racerlab.model import init_model
from racerlab.train import train

TARGET_S = 600


def first_clean_lap(sensor: str, max_speed: float, minutes: float, threads: int = 0) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = init_model(Path(tmp) / "m", sensor=sensor, max_speed=max_speed, race="object_avoidance")
        toml = folder.path / "training.toml"
        toml.write_text(toml.read_text().replace("threads = 0", f"threads = {threads}", 1))
        t0 = time.perf_counter()
        r = train(folder.path, minutes=minutes, stop_at_first_lap=True, progress=False)
        wall = time.perf_counter() - t0
    fl = r.first_lap or {}
    rates = [h["charts/env_steps_per_s"] for h in r.history]
    return {"bench": "object_avoidance_first_clean_lap", "sensor": sensor, "track": "lab_technical",
            "boxes": 3, "max_speed": max_speed, "threads": threads,
            "first_lap_wall_s": round(fl["wall_seconds"], 1) if fl else None,
            "first_lap_env_steps": fl.get("env_steps"), "first_lap_iteration": fl.get("iteration"),
            "lap_time_s": round(r.best_lap_time, 3), "iterations": r.iterations,
            "collect_env_steps_per_s": round(sum(rates) / max(len(rates), 1)), "total_wall_s": round(wall, 1),
            "stopped": r.stopped, "target_s": TARGET_S, "load_avg": round(os.getloadavg()[0], 2)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sensor", choices=["features", "lidar"], default="features")
    ap.add_argument("--max-speed", type=float, default=1.0)
    ap.add_argument("--minutes", type=float, default=15.0, help="give up after this long")
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = all cores)")
    args = ap.parse_args()
    print(json.dumps(first_clean_lap(args.sensor, args.max_speed, args.minutes, args.threads)), flush=True)


if __name__ == "__main__":
    main()
