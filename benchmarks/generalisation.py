"""Share of 20 held-out AWS tracks lapped by a model trained for a bounded time on generated tracks.

For each observation kind it creates a fresh model with `racerlab init --preset generalise` (continuous
actions up to `--max-speed`, AWS default hyperparameters, the example reward; 8 generated circuits,
new ones every 5 iterations; in-training evaluation on racerlab's own lab_technical), trains it for
`--minutes`, then drives one lap without resets on `--count` AWS tracks it never saw (from
RACERLAB_TEST_AWS_TRACKS or ../shared/tracks) and prints one JSON line: the share of tracks lapped
(target >= 0.8), the same under domain randomisation and the drop, the training minutes, iterations
and env steps, and the load average before and after (the machine may be shared).

Kinds: `lidar` (AWS's 64-ray lidar alone, seeing the track borders as walls: AWS tracks have none, so
without walls a lidar sees nothing) and `camera` (the front camera). With `--randomise` the model also
trains under the kind's randomisation (RANDOMISE below); the randomised evaluation always uses it.
`--training single` trains on lab_technical alone instead, as a baseline.

Usage: python benchmarks/generalisation.py [--kinds lidar camera] [--minutes 10] [--count 20] [--randomise]
       [--training generated|single] [--cars 16] [--max-speed 1.5]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from racerlab.evaluate.generalise import evaluate_tracks, held_out_tracks
from racerlab.model import init_model
from racerlab.model.config import RandomiseSettings
from racerlab.train import train

REPO = Path(__file__).resolve().parents[1]
AWS_TRACKS = Path(os.environ.get("RACERLAB_TEST_AWS_TRACKS") or REPO.parent / "shared" / "tracks")
TARGET_SHARE = 0.8
ACTUATORS = {"latency_steps": 1, "steering_gain": 0.1, "throttle_gain": 0.1}
RANDOMISE = {
    "lidar": RandomiseSettings(lidar_noise_m=0.02, **ACTUATORS),
    "camera": RandomiseSettings(camera_noise=4.0, blur=1.0, exposure=0.25, gamma=0.25, lighting=True,
                                pose_yaw_deg=2.0, pose_pitch_deg=2.0, pose_shift_m=0.02, **ACTUATORS),
}
OBSERVATION = {"lidar": "lidar:walls", "camera": "camera"}


def _configure(folder, kind: str, training: str, randomise: bool) -> None:
    """Write the kind's observation (and randomisation) into the model's training.toml."""
    from racerlab.model import TrainingConfig

    cfg: TrainingConfig = folder.config()
    cfg = replace(cfg, run=replace(cfg.run, observation=OBSERVATION[kind]))
    if training == "single":
        cfg = replace(cfg, track=replace(cfg.track, generated=0))
    if randomise:
        cfg = replace(cfg, randomise=RANDOMISE[kind])
    folder.config_path.write_text(cfg.to_toml())


def run(kind: str, args) -> dict:
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        folder = init_model(Path(tmp) / "m", sensor="lidar" if kind == "lidar" else "camera",
                            action_space="continuous", max_speed=args.max_speed, num_cars=args.cars,
                            preset="generalise")
        _configure(folder, kind, args.training, args.randomise)
        t0 = time.perf_counter()
        r = train(folder.path, minutes=args.minutes, progress=False)
        train_min = (time.perf_counter() - t0) / 60
        tracks = held_out_tracks(AWS_TRACKS, args.count, exclude=folder.config().track.names)
        res = evaluate_tracks(folder.path, tracks, trials=args.trials, randomise=RANDOMISE[kind])
    out = res.to_json()
    return {"bench": "generalisation", "observation": OBSERVATION[kind], "training": args.training,
            "trained_randomised": args.randomise, "minutes_asked": args.minutes,
            "training_minutes": round(train_min, 2),
            "iterations": r.iterations, "env_steps": r.env_steps, "cars": args.cars, "max_speed": args.max_speed,
            "held_out_tracks": out["tracks"], "trials_per_track": args.trials,
            "share_completed": out["share_completed"], "target_share": TARGET_SHARE,
            "randomised_share_completed": out["randomised_share_completed"],
            "drop_under_randomisation": out["drop_under_randomisation"],
            "randomisation": RANDOMISE[kind].changed(),
            "lapped": [t["track"] for t in out["per_track"] if t["laps"]],
            "not_lapped": [t["track"] for t in out["per_track"] if not t["laps"]],
            "evaluation_seconds": out["wall_seconds"], "cpu_count": os.cpu_count(),
            "loadavg_1min_before_after": [round(load_before, 2), round(os.getloadavg()[0], 2)]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", nargs="+", default=["lidar"], choices=list(OBSERVATION))
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--count", type=int, default=20)
    ap.add_argument("--trials", type=int, default=3, help="laps per track (they differ only under randomisation)")
    ap.add_argument("--randomise", action="store_true", help="train under the kind's randomisation too")
    ap.add_argument("--training", choices=["generated", "single"], default="generated")
    ap.add_argument("--cars", type=int, default=16)
    ap.add_argument("--max-speed", type=float, default=1.5)
    args = ap.parse_args()
    for kind in args.kinds:
        print(json.dumps(run(kind, args)), flush=True)


if __name__ == "__main__":
    main()
