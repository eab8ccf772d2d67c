"""Time to the first completed greedy evaluation lap, training throughput, and a 10-minute best lap.

Prints one JSON line per measurement (the whole machine is used: torch on all cores):
- `features`: wall-clock seconds and env steps from a fresh model to the first complete greedy
  evaluation lap on the default track (budget <= 180 s);
- `camera`: the same with the 3-layer CNN on camera frames (budget <= 1800 s; the AWS console
  needed about 90 minutes);
- `reinvent_10min`: the best evaluation lap on reInvent2019_track after 10 minutes of `features`
  training, next to the all-time best human-trained lap in the AWS simulator (7.198 s).

Usage: python benchmarks/train_to_first_lap.py [--only features|camera|reinvent] [--reinvent-track PATH]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from racerlab.model import init_model
from racerlab.train import train

REPO = Path(__file__).resolve().parents[1]
REINVENT = REPO.parent / "shared" / "tracks" / "reInvent2019_track.npy"


def first_lap(sensor: str, limit_minutes: float, max_speed: float, track: str | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = init_model(Path(tmp) / "m", track=track, sensor=sensor, max_speed=max_speed)
        t0 = time.perf_counter()
        r = train(folder.path, minutes=limit_minutes, stop_at_first_lap=True)
        wall = time.perf_counter() - t0
    steps_per_s = [h["charts/env_steps_per_s"] for h in r.history]
    fl = r.first_lap or {}
    return {"bench": f"train_to_first_lap_{sensor}", "track": track or "lab_technical", "max_speed": max_speed,
            "first_lap_wall_s": round(fl.get("wall_seconds", float("nan")), 1),
            "first_lap_env_steps": fl.get("env_steps"),
            "first_lap_iteration": fl.get("iteration"), "lap_time_s": round(r.best_lap_time, 3),
            "collect_env_steps_per_s": round(sum(steps_per_s) / max(len(steps_per_s), 1)),
            "overall_env_steps_per_s": round(r.env_steps / wall), "total_wall_s": round(wall, 1),
            "budget_s": 180 if sensor == "features" else 1800}


def reinvent_best_lap(track: Path, minutes: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = init_model(Path(tmp) / "m", track=str(track), max_speed=4.0, action_space="continuous")
        r = train(folder.path, minutes=minutes)
    return {"bench": "reinvent2019_best_lap_after_training", "minutes": minutes, "iterations": r.iterations,
            "env_steps": r.env_steps, "best_eval_lap_s": round(r.best_lap_time, 3),
            "aws_all_time_best_human_trained_s": 7.198}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", choices=["features", "camera", "reinvent"])
    ap.add_argument("--reinvent-track", type=Path, default=REINVENT)
    ap.add_argument("--reinvent-minutes", type=float, default=10.0)
    args = ap.parse_args()
    if args.only in (None, "features"):
        print(json.dumps(first_lap("features", 10, 2.0)), flush=True)
    if args.only in (None, "camera"):
        print(json.dumps(first_lap("camera", 45, 2.0)), flush=True)
    if args.only in (None, "reinvent"):
        print(json.dumps(reinvent_best_lap(args.reinvent_track, args.reinvent_minutes)), flush=True)


if __name__ == "__main__":
    main()
